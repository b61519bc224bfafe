"""Writing commissioning results back into the hardware file, comments and layout kept.

:func:`update_values` edits single values (``("axes", "az", "min") → -284.5``) with tomlkit,
which keeps every comment, blank line, key order and the trailing comment of an edited line.
The new text is validated with :func:`tcs.config.parse_config` *before* anything is written
(a result that would make the file invalid — limits that no longer contain an axis's discrete
positions, min above max — is refused with the file's own messages), then the file is
replaced atomically (temporary file, fsync, rename) keeping the old file's mode, owner and group
(``/etc/tcs/tcs.toml`` is 0640 root:tcs: the service must still read it after a root
``tcs-commission limits --write``). Blocking file I/O; main thread.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import tomlkit
from tomlkit.exceptions import TOMLKitError

from tcs.config import parse_config
from tcs.errors import ConfigErrors
from tcs.pointing.storage import atomic_write_text

from tcs.commission.common import CommissionError, ExitCode


def update_values(path: str | Path, values: Mapping[tuple[str, ...], float]) -> str:
    """Set each key path to its value in the TOML file at ``path``; returns the new text.

    Raises
    ------
    CommissionError
        (exit 2) the file cannot be read or parsed, or a key path does not exist;
        (exit 1) the edited file would not be a valid hardware file (nothing is written).
    """
    path = Path(path)
    try:
        doc = tomlkit.parse(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, TOMLKitError) as exc:
        raise CommissionError(f"{path}: cannot edit: {exc}", ExitCode.USAGE) from None
    for keys, value in values.items():
        table = doc
        for i, key in enumerate(keys[:-1]):
            if key not in table:
                raise CommissionError(f"{path}: no table [{'.'.join(keys[:i + 1])}]", ExitCode.USAGE)
            table = table[key]
        if keys[-1] not in table:
            raise CommissionError(f"{path}: no key {'.'.join(keys)}", ExitCode.USAGE)
        table[keys[-1]] = float(value)
    text = tomlkit.dumps(doc)
    try:
        parse_config(text, str(path))
    except ConfigErrors as exc:
        raise CommissionError(f"not written: the new values would make the hardware file "
                              f"invalid:\n{exc.message}") from None
    atomic_write_text(path, text, keep_mode=True)  # /etc/tcs stays readable by the service
    return text
