"""Hardware configuration: the TOML file that decides the telescope.

Public names: :func:`load_config`, :func:`parse_config`, :class:`HwConfig`, :data:`DEFAULT_CONFIG`.
"""

from tcs.config.hwconfig import DEFAULT_CONFIG, HwConfig, load_config, parse_config

__all__ = ["DEFAULT_CONFIG", "HwConfig", "load_config", "parse_config"]
