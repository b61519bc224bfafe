"""POINTING.POINTINGPARAMS (OpenTCI §14.2): samples, dump files, the fit and named models.

How it works
------------
* ``SAMPLE=1`` records one :class:`~tcs.pointing.model.Sample`: the TARGET's ideal
  mechanical position now (observed place in the orientation in use, no model) and the
  encoder positions of the two main axes (REALPOS, i.e. including the OFFSET the operator set
  to centre the star) and those offsets. With a ``DUMPFILE`` it is appended to that file
  (flushed and fsynced before the SET answers). ``RECORDCOUNT`` counts the samples; writing it
  (any value) erases them. ``LOADFILE=<name>`` replaces the samples by a dump file's and makes
  it the ``DUMPFILE`` (resuming a model).
* ``CALCULATE=1`` fits the model by linear least squares (:func:`~tcs.pointing.model.fit_samples`)
  and makes it the active model; ``2`` also sets the main axes' OFFSET to 0 (the SET ends when
  they got there). Reading gives the fit's RMS on the sky in **arcseconds** (0 before any fit).
  Fitted terms: ``[pointing] fit_terms``, default the spec's 6 mount terms + tube flexure:
  AZ-ZD ``IA IE NPAE CA AN AW TF``; RA-DEC ``IH ID CH NP MA ME TF``.
* The coefficients are variables of their own (degrees, readable and writable): AZ-ZD
  ``IA IE NPAE CA AN AW TF TX``, RA-DEC ``IH ID CH NP MA ME TF`` (TPOINT names, meaning in
  :mod:`tcs.pointing.model`). The active model survives a restart (state store).
* ``LIST`` / ``LOAD`` / ``SAVE`` / ``ERASE`` handle named models, ``<name>.model`` files in
  ``[pointing] model_directory`` (default ``<state dir>/pointing``), saved atomically
  (:class:`~tcs.pointing.storage.ModelStore`): a kill during SAVE leaves the old file or the
  new one. ``LOAD`` reads back the name last loaded or saved.
* Dump file names are plain names (letters, digits, ``_ - + .``) of files in the same
  directory — a client cannot write elsewhere on the cabinet computer.

Every change of the active model re-plans a running tracking at once (the owner's
``model_changed``). File I/O runs in the telescope's worker threads (``run_blocking``); the
SETs that do I/O answer when it is done.

What may touch it
-----------------
The event loop (tree setters); the owner is the POINTING module.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from tcs.errors import ErrorNumber, RequestRefused, TcsError
from tcs.pointing.model import MOUNT_TERMS, FitResult, PointingModel, Sample, fit_samples
from tcs.pointing.storage import ModelStore, append_sample, load_dump, write_dump_header

__all__ = ["PointingParams", "STANDARD_TERMS"]

#: The spec's "6 coefficients for mounting errors plus one tube flexure term", per mount.
STANDARD_TERMS = {"AZ-ZD": ("IA", "IE", "NPAE", "CA", "AN", "AW", "TF"),
                  "RA-DEC": ("IH", "ID", "CH", "NP", "MA", "ME", "TF")}
_FILE_NAME = re.compile(r"[A-Za-z0-9_+\-][A-Za-z0-9_+.\-]{0,99}")


class PointingParams:
    """Domain object of POINTING.POINTINGPARAMS.

    Parameters
    ----------
    owner : the POINTING module: ``mount``, ``latitude``, ``measure()`` → Sample,
        ``dump_header()``, ``model_changed()``, ``persist()``, ``reset_offsets()``,
        ``run_blocking``.
    directory : where named models and dump files live.
    model : the active model at start.
    fit_terms : terms CALCULATE fits (empty: :data:`STANDARD_TERMS` of the mount).
    """

    def __init__(self, owner, directory: Path, model: PointingModel, fit_terms=(),
                 model_name: str = "", dumpfile: str = ""):
        self.owner = owner
        self.directory = Path(directory)
        self.store = ModelStore(self.directory)
        self.model = model
        known = MOUNT_TERMS[model.mount]
        terms = tuple(fit_terms) or STANDARD_TERMS[model.mount]
        bad = [t for t in terms if t not in known]
        if bad:
            raise TcsError(f"[pointing] fit_terms: {bad} are not {model.mount} terms {list(known)}")
        self.fit_terms = terms
        self.samples: list[Sample] = []
        self.last_fit: FitResult | None = None
        self.rms_arcsec = 0.0
        self.model_name = model_name
        self._dumpfile = dumpfile

    # -- coefficients ---------------------------------------------------------------------------
    @property
    def terms(self) -> tuple[str, ...]:
        return self.model.terms

    def coefficient(self, name: str) -> float:
        return self.model.get(name)

    def set_coefficient(self, name: str, value: float) -> None:
        self._activate(self.model.replace(**{name: float(value)}))

    def _activate(self, model: PointingModel) -> None:
        self.model = model
        self.owner.persist()
        self.owner.model_changed()

    # -- samples --------------------------------------------------------------------------------
    @property
    def recordcount(self) -> float:
        return float(len(self.samples))

    def set_recordcount(self, value: float) -> None:
        """Any write erases the samples (the dump file is kept)."""
        self.samples.clear()

    @property
    def sample(self) -> int:
        return 0

    def set_sample(self, value: int):
        """``SAMPLE=1``: record one measurement (appended to DUMPFILE when set)."""
        if int(value) != 1:
            raise RequestRefused("write 1 to SAMPLE to take a measurement", keyword="RANGE")
        sample = self.owner.measure()
        self.samples.append(sample)
        if self._dumpfile:
            path = self._path(self._dumpfile)
            return self.owner.run_blocking(append_sample, path, sample)
        return None

    @property
    def dumpfile(self) -> str:
        return self._dumpfile

    def set_dumpfile(self, name: str):
        """``DUMPFILE=<name>``: append new samples there (a new file gets a header; an
        existing one must be a dump file of this mount). Empty: no dump file."""
        name = str(name).strip()
        if not name:
            self._dumpfile = ""
            self.owner.persist()
            return None
        path = self._path(name)
        header = self.owner.dump_header()

        def prepare() -> None:
            if path.exists():
                old, _samples = load_dump(path)
                if old.mount != header.mount:
                    raise TcsError(f"dump file {name}: mount {old.mount}, this telescope is "
                                   f"{header.mount}", ErrorNumber.INVMODE)
            else:
                self.directory.mkdir(parents=True, exist_ok=True)
                write_dump_header(path, header)

        async def run() -> None:
            await self.owner.run_blocking(prepare)
            self._dumpfile = name
            self.owner.persist()

        return run()

    @property
    def loadfile(self) -> str:
        return ""

    def set_loadfile(self, name: str):
        """``LOADFILE=<name>``: the samples become the file's; it becomes the DUMPFILE."""
        name = str(name).strip()
        path = self._path(name)

        async def run() -> None:
            header, samples = await self.owner.run_blocking(load_dump, path)
            if header.mount != self.model.mount:
                raise TcsError(f"dump file {name}: mount {header.mount}, this telescope is "
                               f"{self.model.mount}", ErrorNumber.INVMODE)
            self.samples = list(samples)
            self._dumpfile = name
            self.owner.persist()

        return run()

    def _path(self, name: str) -> Path:
        if not _FILE_NAME.fullmatch(name) or name.endswith(".model"):
            raise RequestRefused(f"dump file name {name!r}: use 1-100 letters, digits, '_', '-', "
                                 "'+', '.', not starting with '.' nor ending in '.model'", keyword="RANGE")
        return self.directory / name

    # -- the fit --------------------------------------------------------------------------------
    @property
    def calculate(self) -> float:
        return self.rms_arcsec

    def set_calculate(self, value: float):
        """``CALCULATE``: 1 fit and activate; 2 also reset the main axes' OFFSET to 0."""
        value = float(value)
        if value not in (1.0, 2.0):
            raise RequestRefused("CALCULATE is 1 (fit) or 2 (fit and reset the axes' OFFSET)",
                                 keyword="RANGE")
        if value == 2.0:
            self.owner.check_offsets_resettable()
        result = fit_samples(self.samples, mount=self.model.mount, terms=self.fit_terms,
                             latitude=self.owner.latitude)
        self.last_fit = result
        self.rms_arcsec = result.rms_arcsec
        self.model_name = ""
        self._activate(result.model)
        if value == 2.0:
            return self.owner.reset_offsets()
        return None

    # -- named models ---------------------------------------------------------------------------
    @property
    def list(self) -> str:
        return ",".join(self.store.list())

    @property
    def load(self) -> str:
        return self.model_name

    def set_load(self, name: str):
        name = str(name).strip()
        self.store.path(name)   # validates the name at once

        async def run() -> None:
            model: PointingModel = await self.owner.run_blocking(self.store.load, name)
            if model.mount != self.model.mount:
                raise TcsError(f"pointing model {name!r} is for {model.mount}, the mount is "
                               f"{self.model.mount}", ErrorNumber.INVMODE)
            self.model_name = name
            self._activate(PointingModel(model.mount, model.coefficients, self.owner.latitude))

        return run()

    @property
    def save(self) -> str:
        return ""

    def set_save(self, name: str):
        name = str(name).strip()
        self.store.path(name)
        model = self.model
        fit = self.last_fit if self.last_fit is not None and self.last_fit.model == model else None
        errors = fit.errors if fit is not None else None
        report = fit.report() if fit is not None else ""

        async def run() -> None:
            await self.owner.run_blocking(lambda: self.store.save(name, model, errors=errors,
                                                                  report=report))
            self.model_name = name
            self.owner.persist()

        return run()

    @property
    def erase(self) -> str:
        return ""

    def set_erase(self, name: str):
        name = str(name).strip()
        self.store.path(name)

        async def run() -> None:
            await self.owner.run_blocking(self.store.erase, name)
            if self.model_name == name:
                self.model_name = ""
                self.owner.persist()

        return run()

    # -- persistence ----------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {"coefficients": dict(self.model.coefficients), "name": self.model_name,
                "dumpfile": self._dumpfile, "rms": self.rms_arcsec}

