"""EMCY (and 0x603F) error codes decoded into readable :class:`~tcs.errors.HardwareError`\\ s.

The OpenTCI error number (spec Appendix B) of each code is chosen here, once:

=====================  ===========================================  ======================
code                   meaning                                      OpenTCI number
=====================  ===========================================  ======================
0x8612                 position limit (software limit in the drive)  8 ``limit``
0xFF01 / 0xFF02        negative / positive limit switch (sim)       8 ``limit``
0x8130                 heartbeat / life guard (TCS heartbeat lost)  4 ``nocon``
0x8100..0x81FF (rest)  CAN communication (overrun, passive, off)    3 ``confail``
0x8611                 following error                              2 ``libfail``
anything else          over-current, voltage, temperature, encoder  2 ``libfail``
=====================  ===========================================  ======================

A following error is a drive failure (the axis could not follow), not a limit: number 8
would make clients believe a limit switch was hit, so it is ``libfail`` with its own text.
Limit switches on most drives report 0x8612 or a vendor code; the table is extended per
vendor by adding rows (``VENDOR_CODES``).
"""

from __future__ import annotations

from tcs.errors import ErrorNumber, HardwareError

#: Exact codes: code -> (text, OpenTCI number).
CODES: dict[int, tuple[str, int]] = {
    0x1000: ("generic error", ErrorNumber.LIBFAIL),
    0x2310: ("over-current", ErrorNumber.LIBFAIL),
    0x2320: ("short circuit / earth leakage", ErrorNumber.LIBFAIL),
    0x3210: ("DC-link over-voltage", ErrorNumber.LIBFAIL),
    0x3220: ("DC-link under-voltage", ErrorNumber.LIBFAIL),
    0x4210: ("drive over-temperature", ErrorNumber.LIBFAIL),
    0x4310: ("drive temperature", ErrorNumber.LIBFAIL),
    0x5530: ("EEPROM / data storage error", ErrorNumber.LIBFAIL),
    0x6320: ("parameter error", ErrorNumber.LIBFAIL),
    0x7300: ("sensor (encoder) fault", ErrorNumber.LIBFAIL),
    0x7305: ("incremental encoder fault", ErrorNumber.LIBFAIL),
    0x7310: ("speed sensor fault", ErrorNumber.LIBFAIL),
    0x7320: ("position sensor (encoder) fault", ErrorNumber.LIBFAIL),
    0x8110: ("CAN overrun: frames lost", ErrorNumber.CONFAIL),
    0x8120: ("CAN error passive", ErrorNumber.CONFAIL),
    0x8130: ("heartbeat of the TCS lost (life guard)", ErrorNumber.NOCON),
    0x8140: ("recovered from CAN bus-off", ErrorNumber.CONFAIL),
    0x8210: ("PDO too short", ErrorNumber.CONFAIL),
    0x8220: ("PDO too long", ErrorNumber.CONFAIL),
    0x8250: ("RPDO time-out: cyclic setpoints missing", ErrorNumber.CONFAIL),
    0x8611: ("following error", ErrorNumber.LIBFAIL),
    0x8612: ("position limit reached", ErrorNumber.LIMIT),
}

#: Vendor-specific codes (0xFF00..0xFFFF): the simulated drive's limit switches.
VENDOR_CODES: dict[int, tuple[str, int]] = {
    0xFF01: ("negative limit switch", ErrorNumber.LIMIT),
    0xFF02: ("positive limit switch", ErrorNumber.LIMIT),
}

#: Code classes (mask 0xF000 or 0xFF00) for codes not listed.
CLASSES: tuple[tuple[int, int, str, int], ...] = (
    (0xFF00, 0x8100, "CAN communication error", ErrorNumber.CONFAIL),
    (0xF000, 0x2000, "current error", ErrorNumber.LIBFAIL),
    (0xF000, 0x3000, "voltage error", ErrorNumber.LIBFAIL),
    (0xF000, 0x4000, "temperature error", ErrorNumber.LIBFAIL),
    (0xFF00, 0x5000, "device hardware error", ErrorNumber.LIBFAIL),
    (0xF000, 0x6000, "device software error", ErrorNumber.LIBFAIL),
    (0xFF00, 0x7000, "additional module error", ErrorNumber.LIBFAIL),
    (0xF000, 0x7000, "sensor error", ErrorNumber.LIBFAIL),
    (0xF000, 0x8000, "monitoring error", ErrorNumber.LIBFAIL),
    (0xFF00, 0x9000, "external error", ErrorNumber.LIBFAIL),
    (0xFF00, 0xFF00, "device-specific error", ErrorNumber.LIBFAIL),
)


def describe(code: int) -> tuple[str, int]:
    """(text, OpenTCI number) of an EMCY / 0x603F error code."""
    if code in CODES:
        return CODES[code]
    if code in VENDOR_CODES:
        return VENDOR_CODES[code]
    for mask, value, text, number in CLASSES:
        if code & mask == value:
            return text, number
    return "error", ErrorNumber.LIBFAIL


class DriveFault(HardwareError):
    """A drive reported an error code (EMCY or 0x603F); ``code`` keeps the raw value."""

    def __init__(self, device: str, code: int, register: int = 0, data: bytes = b""):
        text, number = describe(code)
        self.code, self.register, self.data = code, register, bytes(data)
        extra = f", data {self.data.hex()}" if any(self.data) else ""
        super().__init__(device, f"{text} (error code 0x{code:04X}{extra})", number)


def decode_emcy(device: str, payload: bytes) -> DriveFault | None:
    """Decode an EMCY frame; None for the error-reset code 0x0000 (or 0x00xx).

    Frames shorter than the 8 bytes of the standard are padded, not dropped.
    """
    data = bytes(payload).ljust(8, b"\0")
    code = data[0] | data[1] << 8
    if code & 0xFF00 == 0:
        return None
    return DriveFault(device, code, data[2], data[3:8])
