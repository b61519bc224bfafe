"""The one declaration of the OpenTSI tree (the successor of OpenTCI served by AsTelOS "Pilar"),
as its clients use it (``docs/opentsi.md``): TELESCOPE, OBJECT, POINTING, POSITION, CURRENT,
AUXILIARY and SERVER.

Every OpenTSI variable name the server answers to is written here and nowhere else; the tree
machinery (``tcs/opentci_server/tree.py``) derives lookup, ``!MEMBERS`` and the reference
(``tools/opentsi_reference.py``) from it. The tree is a view of the same telescope model as the
OpenTCI tree (``docs/architecture.md`` rule 0): the modules bind to the model's objects —
:class:`~tcs.model.operations.Operations` (ready/park, the catalogue target, the verbs of
``POINTING.TRACK``, the set-up of the next verb), the cabinet, the pointing module, the axes,
the peripherals — or to the stateless views of :mod:`tcs.opentsi.views`.
``POSITION.INSTRUMENTAL.<AXIS>`` reuses the OpenTCI generic-axis declarations unchanged.

``POINTING.TRACK`` here is the OpenTSI verb (0 stop, 1 track OBJECT.EQUATORIAL, 2 go to
OBJECT.HORIZONTAL and stop, 3 filter, 4 focus); the OpenTCI tree's ``POINTING.TRACK`` (tracking
orientation) is served only on the OpenTCI port.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

from tcs.opentci_server.opentci import SERVER
from tcs.opentci_server.opentci.axes import AXES, axis_members
from tcs.opentci_server.opentci.enclosure import COVER, COVER_ARRAY, DOME
from tcs.opentci_server.tree import (CONFIGURE, FLOAT, INT, STRING, Tree, module, module_array, var)
from tcs.opentsi import views


@dataclass
class TsiRoot:
    """What the OpenTSI tree is built over: the model, the server, and the stateless views."""

    telescope: Any
    server: Any

    def __post_init__(self):
        cfg = self.telescope.config.opentsi
        self.ops = self.telescope.operations
        self.status = views.StatusView(self.telescope, cfg.error_table(), cfg.error_default,
                                       cfg.warning_default)
        self.position = views.Position(self.telescope)
        self.environment = views.Environment(self.telescope)

    def abort_request(self, cause, awaitable=None) -> None:
        """TPL2 ABORT of a long SET of this tree (POINTING.TRACK, TELESCOPE.READY/POWER):
        the motion it started stops (:meth:`Operations.abort_request`)."""
        self.ops.abort_request(cause, awaitable)


def _zero(_obj) -> int:
    return 0


def _mount_of(sky_object) -> str:
    return sky_object.mount


# ------------------------------------------------------------------------------ TELESCOPE

STATUS = module(
    "STATUS",
    var("GLOBAL", INT, get="global_state",
        info="bit 0 PANIC, 1 ERROR, 2 WARNING, 3 INFO: OR of every module's ERROR_STATE"),
    var("LIST", STRING, get="list_text",
        info="<group>|<level>:<component>|<level>[;…]:<error>|<detail>|<level>|<component>[;…], "
             "groups separated by ','"),
    var("CLEAR", INT, get=_zero, set="clear", min=0, max=15,
        info="acknowledge the modules with ERROR_STATE bits in the mask"),
    var("CLEAR_PANIC", INT, get=_zero, set="clear_panic", min=0, max=15, info="as CLEAR, panic level only"),
    var("CLEAR_ERROR", INT, get=_zero, set="clear_error", min=0, max=15, info="as CLEAR, error level only"),
    var("CLEAR_WARNING", INT, get=_zero, set="clear_warning", min=0, max=15,
        info="as CLEAR, warning level only"),
    var("CLEAR_INFO", INT, get=_zero, set="clear_info", min=0, max=15, info="as CLEAR, info level only"),
    var("LOCAL_MODE", INT, get="local_mode", info="1: local operation (no key switch: always 0)"),
    info="errors of the telescope", bind=lambda root: root.status,
)

CONFIG = module(
    "CONFIG",
    var("MOUNTOPTIONS", STRING, get=lambda r: views.mount_options(r.telescope),
        info="mounts the hardware can do: AZ-ZD, ZD-ZD, HA-DEC"),
    var("MOUNT", STRING, get=lambda r: views.mount_name(r.telescope), info="the active mount"),
    module_array("PORT",
                 var("FILTER", INT, get=lambda axis: len(axis.positions),
                     info="number of filters of the wheel at this port"),
                 info="instrument ports (App. C.2 indices) with a filter wheel",
                 bind=lambda root: root.telescope.axis_array("FILTER")),
    module("LOCAL",
           var("TAI-UTC", FLOAT, get="tai_utc", set="set_tai_utc", min=0.0, max=100.0, wlevel=CONFIGURE,
               info="leap seconds (= LOCAL.TAI-UTC of OpenTCI)"),
           var("UT1-UTC", FLOAT, get="ut1_utc", set="set_ut1_utc", min=-1.0, max=1.0, wlevel=CONFIGURE,
               info="UT1 - UTC, s (= LOCAL.UT1-UTC of OpenTCI)"),
           info="time base", bind=lambda root: root.telescope.local),
    module("ENVIRONMENT",
           var("TEMPERATURE", FLOAT, get="refraction_temperature", set="set_refraction_temperature",
               min=-100.0, max=100.0, info="°C for refraction; writing selects REFRACTION.MODE 2"),
           var("PRESSURE", FLOAT, get="refraction_pressure", set="set_refraction_pressure",
               min=0.0, max=1200.0, info="hPa for refraction; writing selects REFRACTION.MODE 2"),
           info="refraction inputs (POINTING.REFRACTION of OpenTCI)", bind=lambda root: root.environment),
    info="configuration",
)

TELESCOPE = module(
    "TELESCOPE",
    var("READY", INT, get=lambda r: r.ops.ready, set=lambda r, v: r.ops.set_ready(v), min=0, max=1,
        long=True, info="1: power on and reference, returns when operational; 0: stop tracking, "
                        "park, power off"),
    var("READY_STATE", FLOAT, get=lambda r: r.ops.ready_state,
        info="-3 local, -2 emergency stop, -1 errors block, 0 off, 0..1 changing, 1 operational"),
    var("POWER", INT, get=lambda r: r.ops.power, set=lambda r, v: r.ops.set_ready(v), min=0, max=1,
        long=True, info="as READY"),
    var("STOP", INT, get=_zero, set=lambda r, v: (r.ops.halt(), r.telescope.cabinet.stop()) and None,
        min=0, max=1, info="stop all motion and READY sequences; returns at once"),
    var("MOTION_STATE", INT, get=lambda r: r.ops.check_fresh() or r.ops.motion_state,
        info="0 at rest; bit 0 moving, 1 tracking, 3 on target (11: tracking on target), 5 parking"),
    STATUS,
    CONFIG,
    module("ENVIRONMENT",
           var("TEMPERATURE", FLOAT, get="temperature", info="outside temperature, °C (first °C sensor)"),
           var("PRESSURE", FLOAT, get="pressure", info="air pressure, hPa (first hPa sensor)"),
           info="measured weather", bind=lambda root: root.environment),
    info="the whole telescope: power, readiness, motion, errors",
)

# ------------------------------------------------------------------------------ OBJECT

_PASS_FIELDS = (
    ("START", FLOAT, "rise", "UTC (Unix s) the pass rises above the altitude limit (now, if up)"),
    ("END", FLOAT, "set", "UTC (Unix s) it sets below the limit"),
    ("DURATION", FLOAT, "duration", "s"),
    ("MAX_ALT", FLOAT, "max_altitude", "highest altitude, degrees"),
    ("MAX_RATE", FLOAT, "max_rate", "fastest motion on the sky, deg/s"),
    ("MAX_AZ_RATE", FLOAT, "max_az_rate", "fastest AZ of the planned path, deg/s"),
    ("MAX_ZD_RATE", FLOAT, "max_zd_rate", "fastest ZD, deg/s"),
    ("AZ_START", FLOAT, "az_start", "AZ axis position at the rise on the chosen cable-wrap turn"),
    ("AZ_END", FLOAT, "az_end", "AZ axis position at the set"),
    ("KEYHOLE", INT, "keyhole", "1: AZ cannot follow near the zenith and leads (best effort)"),
    ("KEYHOLE_ERROR", FLOAT, "keyhole_error", "largest pointing error there, degrees"),
    ("FEASIBLE", INT, "feasible", "1: the axes can follow the pass (within 90 % of their limits)"),
    ("REASON", STRING, "reason", "why not, when FEASIBLE is 0: the TLE's age, an element set SGP4 "
                                 "cannot propagate, no pass within 24 h, the axis that cannot follow"),
    ("EPOCH_AGE", FLOAT, "epoch_age", "days from the TLE's epoch to now (negative: ahead)"),
)


def _pass_field(obj, field: str):
    planner = getattr(obj, "planner", None)
    if planner is None:
        return None
    if not (obj.tle[0] and obj.tle[1]):   # no TLE yet: no pass, and why
        return {"feasible": 0, "reason": "no TLE: write OBJECT.TLE.LINE1 and LINE2"}.get(field)
    value = getattr(planner(), field)
    return int(value) if isinstance(value, bool) else value


OBJECT = module(
    "OBJECT",
    module("EQUATORIAL",
           var("RA", FLOAT, get="ra_value", set="set_ra", min=0.0, max=24.0,
               info="right ascension, hours (0 until written)"),
           var("DEC", FLOAT, get="dec_value", set="set_dec", min=-90.0, max=90.0, info="declination, degrees"),
           var("EQUINOX", FLOAT, get="equinox", set="set_equinox", min=1900.0, max=2100.0,
               info="Julian equinox of RA/DEC, years (precessed to J2000)"),
           var("EPOCH", FLOAT, get="epoch", set="set_epoch", min=1900.0, max=2100.0,
               info="epoch of the position for proper motion, years (NULL: the equinox)"),
           var("RA_PM", FLOAT, get="ra_pm", set="set_ra_pm", info="proper motion RA·cos Dec, mas/yr"),
           var("DEC_PM", FLOAT, get="dec_pm", set="set_dec_pm", info="proper motion Dec, mas/yr"),
           var("NAME", STRING, get="name", set="set_name", info="name of the object"),
           var("RA_RATE", FLOAT, get="ra_rate_sky", set="set_ra_rate", min=-36000.0, max=36000.0,
               info="differential RA rate on the sky (RA·cos Dec), arcsec/s"),
           var("RA_RATE_TIME", FLOAT, get="ra_rate_time", set="set_ra_rate_time", min=-2400.0, max=2400.0,
               info="the same rate in seconds of time of RA per second (×15: arcsec of RA)"),
           var("DEC_RATE", FLOAT, get="dec_rate", set="set_dec_rate", min=-36000.0, max=36000.0,
               info="differential Dec rate, arcsec/s"),
           info="the target of POINTING.TRACK=1"),
    module("SOLARSYSTEM",
           var("OBJECT", INT, get="solarsystem_index", set="set_solarsystem_object", min=0, max=8,
               info="body for POINTING.TRACK=1: 0 Sun, 1 Mercury, 2 Venus, 3 Mars, 4 Jupiter, "
                    "5 Saturn, 6 Uranus, 7 Neptune, 8 Pluto (JPL DE421)"),
           var("MOON", INT, get="moon", set="set_moon", min=0, max=1, info="1: POINTING.TRACK=1 tracks the Moon"),
           var("NAME", STRING, get="solarsystem_name", set="set_solarsystem_name",
               info="the body by name (sun, moon, mercury … pluto), whatever the index"),
           info="solar-system targets (apparent, topocentric)"),
    module("TLE",
           var("LINE1", STRING, get=lambda o: o.tle[0], set=lambda o, v: o.set_tle(0, v),
               info="line 1 of the two-line elements (quote it)"),
           var("LINE2", STRING, get=lambda o: o.tle[1], set=lambda o, v: o.set_tle(1, v),
               info="line 2 of the two-line elements"),
           var("NAME", STRING, get=lambda o: o.tle[2], set=lambda o, v: o.set_tle(2, v),
               info="name of the satellite"),
           var("ERROR", STRING, get=lambda o: o.tle_error,
               info="why the last LINE1/LINE2 write was refused with RANGE (checksum, length, "
                    "fields, perigee); empty when it was accepted"),
           module("PASS",
                  *(var(name, type_, get=lambda o, f=f: _pass_field(o, f), info=info)
                    for name, type_, f, info in _PASS_FIELDS),
                  info="the pass POINTING.TRACK=1 will follow, planned now (FEASIBLE 0 and REASON "
                       "with the figures NULL: no pass to follow)"),
           info="an Earth satellite (SGP4, topocentric)"),
    module("HORIZONTAL",
           var("AZ", FLOAT, get="az", set="set_az", min=-360.0, max=720.0,
               info="observed azimuth, degrees, north 0 east 90"),
           var("ALT", FLOAT, get="alt", set="set_alt", min=-90.0, max=90.0, info="observed altitude, degrees"),
           var("ZD", FLOAT, get="zd", set="set_zd", min=0.0, max=180.0, info="90 - ALT"),
           info="the position of POINTING.TRACK=2"),
    *(module("INSTRUMENTAL",
             var(n1, FLOAT, get=lambda o: o.instrumental[0], set=lambda o, v: o.set_instrumental(0, v),
                 info=f"{n1} axis position (its TARGETPOS frame) of POINTING.TRACK=2"),
             var(n2, FLOAT, get=lambda o: o.instrumental[1], set=lambda o, v: o.set_instrumental(1, v),
                 info=f"{n2} axis position (its TARGETPOS frame) of POINTING.TRACK=2"),
             info="an axis position for POINTING.TRACK=2 (the kind written last is used)",
             bind=lambda obj, m=mount: obj if _mount_of(obj) == m else None)
      for mount, (n1, n2) in (("AZ-ZD", ("AZ", "ZD")), ("RA-DEC", ("HA", "DEC")))),
    info="the target (kept by the telescope model)", bind=lambda root: root.ops.object,
)

# ------------------------------------------------------------------------------ POINTING


def _track(root, value: int):
    ops = root.ops
    value = int(value)
    if value == 0:
        ops.stop_tracking()
        return None
    return {1: ops.track_object, 2: ops.goto_horizontal, 3: ops.apply_filter, 4: ops.apply_focus}[value]()


def _model(name, type_, info, **kw):
    return var(name, type_, info=info, **kw)


SETUP = module(
    "SETUP",
    module("DEROTATOR",
           var("SYNCMODE", INT, get="derotator_syncmode", set="set_derotator_syncmode", min=0, max=5,
               info="0 off; else the derotator at the active port follows the field rotation"),
           var("OFFSET", FLOAT, get="derotator_offset", set="set_derotator_offset", min=-360.0, max=360.0,
               info="position angle on the sky, degrees: added to the field angle the derotator follows"),
           info="derotator following"),
    module("DOME",
           var("SYNCMODE", INT, get="dome_syncmode", set="set_dome_syncmode", min=0, max=5,
               info="0 off; else DOME[0] follows the target when off by more than MAX_DEVIATION"),
           var("MAX_DEVIATION", FLOAT, get=lambda s: _pointing_of(s).dome_deviation,
               set=lambda s, v: _pointing_of(s).set_dome_deviation(v), min=0.0, max=180.0,
               info="degrees (POINTING.DOME_DEVIATION of OpenTCI)"),
           var("OFFSET", FLOAT, get="dome_offset", set="set_dome_offset", min=-180.0, max=180.0,
               info="degrees (stored; see docs/opentsi.md)"),
           info="dome following"),
    module("FOCUS",
           var("SYNCMODE", INT, get="focus_syncmode", set="set_focus_syncmode", min=0, max=255,
               info="focus model bits (stored; only bit 0, the plain position, is applied)"),
           var("POSITION", FLOAT, get="focus_position", set="set_focus_position",
               info="mm: applied by POINTING.TRACK=4"),
           info="focus"),
    module("FILTER",
           var("INDEX", INT, get="filter_index", set=lambda s, v: s.owner.set_filter_index(v), min=0,
               info="0..n-1: applied by POINTING.TRACK=3; selects NAME"),
           var("NAME", STRING, get=lambda s: s.owner.filter_name, info="name of filter INDEX"),
           info="filter wheel at the active port"),
    var("USE_PORT", INT, get=lambda s: s.owner.active_port() or 0,
        set=lambda s, v: _mirror_of(s).set_target(v), long=True, min=0, max=11,
        info="active instrument port (MIRROR); writing turns M3, returns on arrival"),
    var("OPTIMIZATION", INT, get="optimization", set="set_optimization", min=0, max=2,
        info="0 none, 1 longest tracking (OpenTCI TRACK 2), 2 shortest slew (TRACK 4)"),
    var("ORIENTATION", INT, get="orientation", set="set_orientation", min=0, max=2,
        info="0 normal, 1 reverse, 2 automatic"),
    var("MIN_TRACKTIME", FLOAT, get="min_tracktime", set="set_min_tracktime", min=0.0,
        info="s (stored; the orientation choice plans the whole planning horizon)"),
    info="how the next POINTING.TRACK is carried out", bind=lambda root: _setup(root),
)


class _SetupView:
    """The set-up with a back reference to its operations (for filters and the port)."""

    def __init__(self, ops):
        self.owner = ops

    def __getattr__(self, name):
        return getattr(self.owner.setup, name)

    def abort_request(self, cause, awaitable=None) -> None:
        """ABORT of USE_PORT: the M3 move halts (:meth:`Operations.abort_request`)."""
        self.owner.abort_request(cause, awaitable)


def _setup(root):
    return _SetupView(root.ops)


def _pointing_of(setup_view):
    p = setup_view.owner.pointing
    if p is None:
        from tcs.errors import ErrorNumber, TcsError
        raise TcsError("no POINTING module", ErrorNumber.INVMODE)
    return p


def _mirror_of(setup_view):
    m = setup_view.owner.telescope.axis("MIRROR")
    if m is None:
        from tcs.errors import ErrorNumber, TcsError
        raise TcsError("no MIRROR (M3)", ErrorNumber.INVMODE)
    return m


def _params(root):
    p = root.telescope.pointing
    return p.params if p is not None else None


def _load(params, value: int):
    if int(value) != 1:
        from tcs.errors import RangeRefused
        raise RangeRefused("LOAD=2 (append) is not supported: LOAD=1 loads FILE's samples")
    return params.set_loadfile(params.dumpfile)


def _model_type(params, value: int):
    if int(value) != 0:
        from tcs.errors import RangeRefused
        raise RangeRefused("only the classic model (TYPE 0) exists")


MODEL = module(
    "MODEL",
    var("CLEAR", INT, get=_zero, set=lambda p, v: p.set_recordcount(0), min=1, max=1,
        info="1: erase the measurements (POINTINGPARAMS.RECORDCOUNT=0)"),
    var("FILE", STRING, get="dumpfile", set=lambda p, v: p.set_dumpfile(os.path.basename(str(v))),
        info="measurement file; a path is reduced to its name in the model directory"),
    var("AUTO_SAVE", INT, get=lambda p: 1, set=lambda p, v: None, min=0, max=1,
        info="measurements are always appended to FILE as taken (reads 1)"),
    var("ADD", STRING, get=lambda p: "", set=lambda p, v: p.set_sample(1),
        info="add a measurement at the current position (POINTINGPARAMS.SAMPLE=1); the name is dropped"),
    var("SAVE", INT, get=_zero, set=lambda p, v: None, min=0, max=1,
        info="measurements are saved as taken: accepted, nothing to do"),
    var("COUNT", INT, get=lambda p: int(p.recordcount), info="number of measurements"),
    var("TYPE", INT, get=_zero, set=_model_type, min=-1, max=1, info="0 classic (the only one)"),
    var("CALCULATE", FLOAT, get="calculate", set="set_calculate", min=1.0, max=2.0, long=True,
        info="1 fit, 2 fit and reset the offsets; reads the RMS, arcsec"),
    var("FILE_LIST", STRING, get="list", info="saved models, comma-separated"),
    var("LOAD", INT, get=_zero, set=_load, min=1, max=2, info="1: load FILE's measurements"),
    info="pointing model (POINTING.POINTINGPARAMS of OpenTCI)", bind=_params,
)

POINTING = module(
    "POINTING",
    var("TRACK", INT, get=lambda r: 1 if r.telescope.pointing is not None and r.telescope.pointing.track else 0,
        set=_track, min=0, max=4, long=True,
        info="0 stop; 1 track OBJECT.EQUATORIAL (returns once tracking runs); 2 go to "
             "OBJECT.HORIZONTAL and stop; 3 SETUP.FILTER.INDEX; 4 SETUP.FOCUS.POSITION (return on arrival)"),
    var("SLEWTIME", FLOAT, get=lambda r: r.telescope.pointing.slewingtime,
        info="s until the axes reach the target (POINTING.SLEWINGTIME)"),
    SETUP,
    MODEL,
    info="commands and their set-up",
)

# ------------------------------------------------------------------------------ POSITION

INSTRUMENTAL = module(
    "INSTRUMENTAL",
    *AXES,
    module("PORT_SELECT", *axis_members(), info="M3: the active port",
           bind=lambda root: root.telescope.axis("MIRROR")),
    DOME, COVER, COVER_ARRAY,
    info="the OpenTCI generic axes, unchanged",
)

POSITION = module(
    "POSITION",
    module("EQUATORIAL",
           var("RA_J2000", FLOAT, get="ra_j2000", info="hours, ICRS (POINTING.CURRENT.RA)"),
           var("DEC_J2000", FLOAT, get="dec_j2000", info="degrees, ICRS"),
           var("RA_CURRENT", FLOAT, get="ra_current", info="apparent RA of date, hours"),
           var("DEC_CURRENT", FLOAT, get="dec_current", info="apparent Dec of date, degrees"),
           var("PARALLACTIC_ANGLE", FLOAT, get="parallactic_angle", info="degrees"),
           info="where the telescope points", bind=lambda root: root.position),
    module("HORIZONTAL",
           var("AZ", FLOAT, get="az", info="observed azimuth, degrees, north 0 east 90 (model removed)"),
           var("ALT", FLOAT, get="alt", info="observed altitude, degrees"),
           var("ZD", FLOAT, get="zd", info="observed zenith distance, degrees"),
           var("DOME", FLOAT, get="dome", info="dome azimuth (DOME[0].REALPOS), degrees"),
           var("DEROTATOR", FLOAT, get="derotator", info="REALPOS of the derotator at the active port"),
           info="where the telescope points", bind=lambda root: root.position),
    module("LOCAL",
           var("UTC", FLOAT, get="utc", info="UTC, s since 1970"),
           var("SIDEREAL_TIME", FLOAT, get="sidereal_time", info="local apparent sidereal time, hours"),
           var("JD", FLOAT, get="jd", info="Julian date (UTC)"),
           var("LATITUDE", FLOAT, get=lambda p: p._t.local.latitude, info="degrees north"),
           var("LONGITUDE", FLOAT, get=lambda p: p._t.local.longitude, info="degrees east"),
           var("HEIGHT", FLOAT, get=lambda p: p._t.local.height, info="m"),
           info="time and site", bind=lambda root: root.position),
    INSTRUMENTAL,
    info="the actual state",
)

# ------------------------------------------------------------------------------ CURRENT


def _pointing(root):
    return root.telescope.pointing


CURRENT = module(
    "CURRENT",
    var("TRACK", INT, get=lambda p: 1 if p.track else 0, info="1 while tracking"),
    var("TRACKTIME", FLOAT, get="tracktime", info="s of tracking left before a limit (NULL: not tracking)"),
    var("DEROTATOR_OFFSET", FLOAT, get=lambda p: p.telescope.operations.setup.derotator_offset,
        info="position angle in use, degrees"),
    var("TARGETDISTANCE", FLOAT, get="targetdistance", info="degrees (POINTING.TARGETDISTANCE)"),
    info="the running target", bind=_pointing,
)

# ------------------------------------------------------------------------------ AUXILIARY

AUXILIARY = module(
    "AUXILIARY",
    module_array("SENSOR",
                 var("VALUE", FLOAT, get="value", info="reading"),
                 var("DESCRIPTION", STRING, get="description", info="what it measures"),
                 var("UNITY", STRING, get="unit", info="unit (chimera's spelling)"),
                 var("UNIT", STRING, get="unit", info="unit"),
                 var("NAME", STRING, get="name", info="name"),
                 info="sensors ([opentsi] sensors maps them onto SENSOR[])",
                 bind=lambda root: views.aux_sensors(root.telescope)),
    module("COVER",
           var("TARGETPOS", INT, get="targetpos", set="set_targetpos", min=0, max=1, long=True,
               info="1 open, 0 close; returns at the end position"),
           var("REALPOS", FLOAT, get="realpos", info="0 closed .. 1 open"),
           info="mirror cover", bind=lambda root: views.covers(root.telescope)),
    module("DOME",
           var("TARGETPOS", INT, get="targetpos", set="set_targetpos", min=0, max=7, long=True,
               info="bit 0 all shutters, bit 1 slit, bit 2 flap; 0 closes"),
           var("REALPOS", FLOAT, get="realpos", info="0 closed .. 1 open (most open shutter)"),
           var("OPEN_MASK", INT, get="open_mask", info="bit 1 slit open, bit 2 flap open"),
           info="dome shutters", bind=lambda root: views.dome_shutters(root.telescope)),
    module("PADDLE",
           var("BRIGHTNESS", FLOAT, get="brightness", set="set_brightness", min=0.0, max=1.0,
               info="hand paddle light (CABINET.MANUAL_CONTROL.BRIGHTNESS)"),
           info="hand paddle", bind=lambda root: root.telescope.cabinet.manual_control),
    info="auxiliary devices",
)

#: The modules of the OpenTSI tree in the order they are numbered.
OPENTSI = (SERVER, TELESCOPE, OBJECT, POINTING, POSITION, CURRENT, AUXILIARY)


def build_opentsi_tree(telescope: Any, server: Any) -> Tree:
    return Tree.build(OPENTSI, TsiRoot(telescope, server), info="OpenTSI telescope")


__all__ = ["OPENTSI", "TsiRoot", "build_opentsi_tree"]
