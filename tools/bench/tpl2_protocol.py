"""Benchmark of the pure TPL2 core: CPU time to parse a 20-variable GET and format its reply.

Run: ``python3 tools/bench/tpl2_protocol.py``. Prints the figures, then (last line) one JSON
object with them. The target is a whole GET round (parse + 20 values formatted + 22 reply
lines encoded) in well under 1 ms of CPU.
"""

from __future__ import annotations

import json
import time

from tcs.opentci_server.messages import CommandComplete, CommandOk, DataInline, Set
from tcs.opentci_server.paths import parse_object
from tcs.opentci_server.protocol import Tpl2Connection
from tcs.opentci_server.values import format_value

VARIABLES = [f"POSITION.INSTRUMENTAL.AXIS[{i % 4}].VARIABLE_{i:02d}" for i in range(18)] + [
    "TELESCOPE.READY_STATE",
    "TELESCOPE.STATUS.LIST!TYPE",
]
GET_LINE = ("12345 GET " + ";".join(VARIABLES) + "\n").encode("ascii")
SET_LINE = b'77 SET POINTING.TARGET.RA="12.5";POINTING.TARGET.DEC=-30.25;POINTING.TRACK=1\n'
VALUES = [123.456789 * (i + 1) for i in range(19)] + ["ok, \"quoted\" text"]


def per_call_us(fn, n: int) -> float:
    """Best of 5 runs of n calls, in microseconds of CPU per call."""
    best = float("inf")
    for _ in range(5):
        t0 = time.process_time()
        for _ in range(n):
            fn()
        best = min(best, time.process_time() - t0)
    return best / n * 1e6


def main() -> None:
    conn = Tpl2Connection()

    def parse_get():
        (msg,) = conn.receive(GET_LINE)
        return msg

    def parse_get_cold():
        parse_object.cache_clear()
        return parse_get()

    msg = parse_get()

    def reply():
        lines = [CommandOk(msg.cmd_id)]
        for ref, v in zip(msg.objects, VALUES):
            lines.append(DataInline(msg.cmd_id, ref.text, (format_value(v),)))
        lines.append(CommandComplete(msg.cmd_id))
        return conn.send_all(lines)

    def round_trip():
        parse_get()
        reply()

    def parse_set():
        (m,) = conn.receive(SET_LINE)
        assert type(m) is Set

    figures = {
        "get20_parse_us": per_call_us(parse_get, 2000),
        "get20_parse_cold_cache_us": per_call_us(parse_get_cold, 500),
        "get20_reply_format_us": per_call_us(reply, 2000),
        "get20_round_us": per_call_us(round_trip, 2000),
        "set3_parse_us": per_call_us(parse_set, 2000),
    }
    for key, value in figures.items():
        print(f"{key:28s} {value:8.1f} us")
    print(json.dumps({k: round(v, 2) for k, v in figures.items()}))


if __name__ == "__main__":
    main()
