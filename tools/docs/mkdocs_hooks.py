"""MkDocs hook (``hooks:`` in ``mkdocs.yml``): the generated pages of the documentation.

At every ``mkdocs build`` / ``mkdocs serve``, :func:`on_files` adds pages that exist only in
memory (nothing is written into ``docs/``, so nothing generated is ever committed or stale):

* ``reference/hwconfig.md`` — every key of the hardware file (``gen_hwconfig_reference.py``);
* ``reference/opentci.md``, ``reference/opentsi.md``, ``reference/alpaca.md``, ``reference/indi.md`` — the front ends'
  variables and devices, read from a service of ``hwconfig/sim.toml`` started on free loopback
  ports (``gen_frontend_reference.py``; a few seconds);
* ``reference/codes.md`` — event/error numbers, drive EMCY codes, SDO aborts, ASCOM errors
  (``gen_codes_reference.py``).

The project's ``README.md`` is the repository's front page, not a page of the site: it links
into ``docs/`` by path (which the site could not resolve), and ``index.md`` is the site's own.

``TCS_DOCS_CONFIG`` names another hardware file for the front-end references. Only MkDocs
loads this module.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
for p in (ROOT, ROOT / "tools", HERE):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

import gen_codes_reference  # noqa: E402
import gen_frontend_reference  # noqa: E402
import gen_hwconfig_reference  # noqa: E402


def generated_pages() -> dict[str, str]:
    """{path inside docs/: Markdown} of every generated page."""
    from tcs.config import DEFAULT_CONFIG

    config = Path(os.environ.get("TCS_DOCS_CONFIG") or DEFAULT_CONFIG)
    pages = {"reference/hwconfig.md": gen_hwconfig_reference.render(),
             "reference/codes.md": gen_codes_reference.render()}
    for name, text in gen_frontend_reference.render_all(config).items():
        pages[f"reference/{name}"] = text
    return pages


def on_files(files, config):
    from mkdocs.structure.files import File

    for src_uri, content in generated_pages().items():
        files.append(File.generated(config, src_uri, content=content))
    return files
