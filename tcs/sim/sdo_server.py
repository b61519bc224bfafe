"""CiA-301 SDO server of a simulated node: expedited and segmented transfers over an ObjectStore.

Pure protocol: :meth:`SdoServer.handle` takes the 8 data bytes of a request (COB-ID
0x600 + node) and returns the 8-byte response (for 0x580 + node) or ``None`` when nothing is
to be answered. The node decides whether to call it at all (a dead node does not) and sends
the answer.

Block transfers are not supported: block upload and block download requests are aborted with
0x05040001 (command specifier not valid), as drives without block transfer do. A segmented
download is checked against the object when its last segment arrives. An object the model
cannot encode (a DOMAIN without a value …) answers 0x08000000 instead of taking the node down.
"""

from __future__ import annotations

import struct

from tcs.sim.object_store import (ABORT_COMMAND, ABORT_GENERAL, ABORT_READ_ONLY, ABORT_TOGGLE,
                                  ObjectStore, SdoAbort)

_HEADER = struct.Struct("<BHB")

# client command specifiers (bits 5-7 of byte 0)
_CCS_DOWNLOAD_SEGMENT = 0
_CCS_INIT_DOWNLOAD = 1
_CCS_INIT_UPLOAD = 2
_CCS_UPLOAD_SEGMENT = 3
_CCS_ABORT = 4
_CCS_BLOCK_UPLOAD = 5
_CCS_BLOCK_DOWNLOAD = 6


def abort_frame(index: int, sub: int, code: int) -> bytes:
    """The 8 bytes of an abort transfer response."""
    return struct.pack("<BHBL", 0x80, index, sub, code)


class SdoServer:
    """The state of one SDO server channel (one transfer at a time, as in CiA-301)."""

    def __init__(self, store: ObjectStore):
        self.store = store
        self._index = 0
        self._sub = 0
        self._toggle = 0
        self._upload: bytearray | None = None
        self._download: bytearray | None = None
        self.refuse_code: int | None = None  # abort every request with this code when set

    def reset(self) -> None:
        self._upload = None
        self._download = None
        self._toggle = 0

    def handle(self, data: bytes) -> bytes | None:
        """Answer one request; every refusal becomes an abort frame."""
        if len(data) < 8:
            data = bytes(data) + bytes(8 - len(data))
        ccs = data[0] >> 5
        if ccs in (_CCS_INIT_DOWNLOAD, _CCS_INIT_UPLOAD, _CCS_BLOCK_UPLOAD, _CCS_BLOCK_DOWNLOAD):
            _, self._index, self._sub = _HEADER.unpack_from(data)
        try:
            if ccs == _CCS_ABORT:
                self.reset()
                return None
            if self.refuse_code is not None:
                self.reset()
                raise SdoAbort(self.refuse_code)
            if ccs == _CCS_INIT_UPLOAD:
                return self._init_upload()
            if ccs == _CCS_UPLOAD_SEGMENT:
                return self._upload_segment(data[0])
            if ccs == _CCS_INIT_DOWNLOAD:
                return self._init_download(data)
            if ccs == _CCS_DOWNLOAD_SEGMENT:
                return self._download_segment(data)
            raise SdoAbort(ABORT_COMMAND)
        except SdoAbort as exc:
            self.reset()
            return abort_frame(self._index, self._sub, exc.code)
        except Exception:  # never crash the node on an odd object: a general error
            self.reset()
            return abort_frame(self._index, self._sub, ABORT_GENERAL)

    def _init_upload(self) -> bytes:
        payload = self.store.read_bytes(self._index, self._sub)
        self.reset()
        if len(payload) <= 4:
            command = 0x43 | ((4 - len(payload)) << 2)
            return _HEADER.pack(command, self._index, self._sub) + payload.ljust(4, b"\0")
        self._upload = bytearray(payload)
        return _HEADER.pack(0x41, self._index, self._sub) + struct.pack("<L", len(payload))

    def _upload_segment(self, command: int) -> bytes:
        if self._upload is None:
            raise SdoAbort(ABORT_COMMAND)
        toggle = command & 0x10
        if toggle != self._toggle:
            raise SdoAbort(ABORT_TOGGLE)
        chunk = bytes(self._upload[:7])
        del self._upload[:7]
        response = 0x00 | toggle | ((7 - len(chunk)) << 1)
        if not self._upload:
            response |= 0x01
            self._upload = None
        self._toggle ^= 0x10
        return bytes([response]) + chunk.ljust(7, b"\0")

    def _init_download(self, data: bytes) -> bytes:
        self.reset()
        command = data[0]
        if command & 0x02:  # expedited
            size = 4 - ((command >> 2) & 0x3) if command & 0x01 else 4
            self.store.write_bytes(self._index, self._sub, bytes(data[4:4 + size]))
        else:
            # Check existence and access at once, as devices do, before taking segments.
            var = self.store.variable(self._index, self._sub)
            if not var.writable:
                raise SdoAbort(ABORT_READ_ONLY)
            self._download = bytearray()
        return _HEADER.pack(0x60, self._index, self._sub) + bytes(4)

    def _download_segment(self, data: bytes) -> bytes:
        if self._download is None:
            raise SdoAbort(ABORT_COMMAND)
        command = data[0]
        toggle = command & 0x10
        if toggle != self._toggle:
            raise SdoAbort(ABORT_TOGGLE)
        unused = (command >> 1) & 0x7
        self._download.extend(data[1:8 - unused])
        self._toggle ^= 0x10
        if command & 0x01:
            payload = bytes(self._download)
            self._download = None
            self.store.write_bytes(self._index, self._sub, payload)
        return bytes([0x20 | toggle]) + bytes(7)
