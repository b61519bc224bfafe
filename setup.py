"""Build glue that pyproject.toml cannot say: ``hwconfig/`` (kept at the top of the source tree)
is installed as the package ``tcs_hwconfig`` so that the shipped hardware files and EDS are
package data (found by ``tcs.resources``), in a wheel and in an editable install alike."""

from setuptools import find_packages, setup

setup(
    packages=find_packages(include=["tcs", "tcs.*"]) + ["tcs_hwconfig"],
    package_dir={"tcs_hwconfig": "hwconfig"},
    # every hardware file and EDS, also in sub-folders (vendor EDS files); data files that
    # modules of tcs may keep next to them
    package_data={"tcs_hwconfig": ["*.toml", "**/*.toml", "**/*.eds", "**/*.EDS"],
                  "tcs": ["**/*.toml", "**/*.json", "**/*.csv", "web/static/*"]},
)
