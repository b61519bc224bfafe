"""The whole hardware file: :class:`HwConfig` and :func:`load_config`.

One file decides the telescope (``docs/architecture.md`` rule 1). ``load_config`` reads the
TOML, validates every section and raises :class:`~tcs.errors.ConfigErrors` listing each problem
as ``file: key.path: problem``; the command-line tools print that and exit with status 2 —
never a traceback. Paths inside the file (EDS files, state directory) are relative to the
file's own directory.

Hardware sections are added here as single fields, one per concern, each defined in its own
module.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from tcs.config.alpaca import AlpacaSection
from tcs.config.can import CanSection, DriveSection, check_can_drives
from tcs.config.schema import build, setting
from tcs.config.gps import GpsSection
from tcs.config.modules import (CoverSection, DomeSection, InterlockSection, SensorSection,
                                 SwitchSection, check_modules)
from tcs.config.opentsi import OpenTsiSection
from tcs.config.plc import PlcSection
from tcs.config.pointing import PointingSection
from tcs.config.envelope import EnvelopeSection
from tcs.config.sections import (CabinetSection, MountSection, ServerSection, SiteSection,
                                 StateSection, TimeSection, UserSection)
from tcs.config.axes import AxisSection, SimulationSection, check_axes
from tcs.config.web import WebSection
from tcs.config.indi import IndiSection
from tcs.errors import ConfigError, ConfigErrors
from tcs.resources import hwconfig_file

#: The source tree (tests and tools find ``hwconfig/`` there); installed code uses DEFAULT_CONFIG.
PACKAGE_ROOT = Path(__file__).resolve().parent.parent.parent
#: The simulated telescope, shipped as package data (:mod:`tcs.resources`).
DEFAULT_CONFIG = hwconfig_file("sim.toml")


@dataclass(frozen=True)
class HwConfig:
    server: ServerSection = setting(factory=ServerSection, doc="the TPL2 server: address, limits, TLS")
    users: list[UserSection] = setting(factory=tuple, doc="who may log in (a service needs at least one)")
    site: SiteSection = setting(factory=SiteSection, doc="where the telescope is (a real one needs it)")
    time: TimeSection = setting(factory=TimeSection, doc="TAI-UTC and UT1-UTC")
    mount: MountSection = setting(factory=MountSection, doc="the mount type (CONFIG.MOUNT)")
    state: StateSection = setting(factory=StateSection, doc="where persistent state is kept")
    cabinet: CabinetSection = setting(factory=CabinetSection, doc="texts of CABINET.SETUP")
    plcs: dict[str, PlcSection] = setting(factory=dict, doc="Modbus PLCs and their register maps "
                                                            "(tcs.config.plc)")
    gps: GpsSection | None = setting(None, doc="the GPS receiver (tcs.config.gps)")
    can: CanSection | None = setting(None, doc="the CAN bus of the drives (tcs.config.can)")
    drives: dict[str, DriveSection] = setting(factory=dict, doc="CiA-402 drives by name (tcs.config.can)")
    axes: dict[str, AxisSection] = setting(factory=dict, doc="OpenTCI axes by name (tcs.config.axes)")
    simulation: SimulationSection | None = setting(None, doc="drives simulated in-process (tcs.config.axes)")
    pointing: PointingSection = setting(factory=PointingSection, doc="the POINTING module (tcs.config.pointing)")
    envelope: EnvelopeSection = setting(factory=EnvelopeSection, doc="the safety envelope: Sun cone, "
                                        "horizon table, keep-out zones (tcs.config.envelope)")
    dome: DomeSection | None = setting(None, doc="DOME[] and CONFIG.DOME on PLC axes (tcs.config.modules)")
    covers: list[CoverSection] = setting(factory=tuple, doc="COVER / COVER[] on PLC axes (tcs.config.modules)")
    sensors: list[SensorSection] = setting(factory=tuple, doc="SENSOR[] on PLC points (tcs.config.modules)")
    switches: list[SwitchSection] = setting(factory=tuple, doc="SWITCH[] on PLC points (tcs.config.modules)")
    interlocks: InterlockSection | None = setting(None, doc="weather interlock of dome and covers (tcs.config.modules)")
    opentsi: OpenTsiSection = setting(factory=OpenTsiSection, doc="names used by the OpenTSI tree (tcs.config.opentsi)")
    alpaca: AlpacaSection = setting(factory=AlpacaSection, doc="the ASCOM Alpaca front end (tcs.config.alpaca)")
    web: WebSection = setting(factory=WebSection, doc="the read-only status page and Prometheus metrics (tcs.config.web)")
    indi: IndiSection = setting(factory=IndiSection, doc="the INDI devices (tcs.config.indi)")
    # Set by load_config, not by the file.
    source: Path = field(default=Path("<memory>"), init=False, compare=False)
    #: The top-level tables and keys the file itself wrote (a section left to its defaults is
    #: not in here). Like ``source``, ``dataclasses.replace`` does not carry it over: check
    #: :meth:`service_problems` on the loaded file.
    written: frozenset[str] = field(default=frozenset(), init=False, compare=False)

    def check(self):
        problems = []
        names = [u.name for u in self.users]
        for i, name in enumerate(names):
            if name in names[:i]:
                problems.append((f"users[{i}].name", f"duplicate user {name!r}"))
        if self.server.implicit_auth and self.server.implicit_user not in names:
            problems.append(("server.implicit_user",
                             f"implicit_auth needs implicit_user to name one of the users {names}"))
        problems.extend(check_can_drives(self.can, self.drives))
        problems.extend(check_axes(self))
        problems.extend(check_modules(self))
        return problems

    @property
    def simulated(self) -> bool:
        """Whether the file describes a simulated telescope (some of its hardware is simulated:
        ``[simulation]`` drives, python-can's virtual bus, ``sim`` tables of PLCs or GPS)."""
        return (self.simulation is not None
                or (self.can is not None and self.can.interface == "virtual")
                or any(plc.sim is not None for plc in self.plcs.values())
                or (self.gps is not None and getattr(self.gps, "sim", None) is not None))

    def service_problems(self) -> list[ConfigError]:
        """What keeps this (valid) file from running a service: no user could log in, or a real
        telescope without its ``[site]`` (which would silently mean 0°, 0°, 0 m). The tools
        (``tcs-commission``, tests) do not need either; ``tcs-server`` refuses to start."""
        file = str(self.source)
        problems = []
        if not self.users:
            problems.append(ConfigError(file, "users", "no [[users]]: nobody could log in; make one "
                                        "with `tcs-passwd NAME` and paste its [[users]] table here"))
        if "site" not in self.written and not self.simulated:
            problems.append(ConfigError(file, "site", "missing: a real telescope needs its [site] "
                                        "latitude, longitude and height"))
        return problems

    @property
    def mount_options(self) -> tuple[str, ...]:
        return tuple(self.mount.options) or (self.mount.type,)

    def resolve(self, path: str) -> Path:
        """A path written in the file, relative to the file's directory."""
        p = Path(os.path.expanduser(path))
        return p if p.is_absolute() else (self.source.parent / p)

    def state_dir(self) -> Path:
        """Directory for persistent state (created on first use by the state store)."""
        if self.state.path:
            return self.resolve(self.state.path)
        if os.environ.get("STATE_DIRECTORY"):  # systemd StateDirectory=
            return Path(os.environ["STATE_DIRECTORY"].split(":")[0])
        base = os.environ.get("XDG_STATE_HOME") or os.path.expanduser("~/.local/state")
        return Path(base) / "tcs" / self.source.stem


def parse_config(text: str, file: str = "<memory>") -> HwConfig:
    """Validate TOML ``text``; raise ConfigErrors naming ``file`` on any problem."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigErrors([ConfigError(file, "", f"not valid TOML: {exc}")]) from None
    config, errors = build(HwConfig, data, file)
    if errors:
        raise ConfigErrors(errors)
    object.__setattr__(config, "source", Path(file).resolve() if file != "<memory>" else Path(file))
    object.__setattr__(config, "written", frozenset(data))
    from tcs.drivers.eds_check import check_config  # each drive against its EDS
    problems, _ = check_config(config.can, dict(config.drives), dict(config.axes), config.resolve, file)
    if problems:
        raise ConfigErrors(problems)
    return config


def load_config(path: str | os.PathLike | None = None) -> HwConfig:
    """Read and validate a hardware file (default: the simulated telescope ``hwconfig/sim.toml``)."""
    path = Path(path) if path is not None else DEFAULT_CONFIG
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigErrors([ConfigError(str(path), "", f"cannot read: {exc.strerror or exc}")]) from None
    except UnicodeDecodeError:
        raise ConfigErrors([ConfigError(str(path), "", "not UTF-8 text")]) from None
    return parse_config(text, str(path))
