"""How much slower than real hardware this guest runs the simulated telescope, printed as the
whole number the checks stretch their protocol times by (``hwfile.py --slowdown``):
    python slowdown.py [--floor N]

A fixed piece of interpreter work (the kind the simulator, the control loop and the service do)
is timed here and compared with :data:`NATIVE` (the same work on one core of a 2024 x86 host,
measured natively). The stack of the checks — tcs-sim's drives, the TCS's control process and
its service in one 2-vCPU guest — needs roughly a third of a native core at a 10 ms cycle, so
it fits a guest ``F`` times slower with the cycle and every supervision time stretched by
about ``0.75 F`` (headroom for the service's planning bursts). Software emulation ranges
from ~6x (a quiet host) to 11–17x (a busy one, measured 2026-11-26): a fixed factor of 5 fitted
the first and faulted the drives (following error, RPDO time-out) on the second. The floor
(``--floor``, default 1) is the least factor printed, :data:`CEILING` the most (the hardware
file's SYNC period may not pass 0.1 s: 10 ms × 10). The measurement goes to stderr.
"""

import argparse
import math
import sys
import time

NATIVE = 0.063  # s for work() on a native core (2024 x86, Python 3.11)
CEILING = 10


def work() -> float:
    t = time.perf_counter()
    s = 0
    for i in range(1_000_000):
        s += i * i % 7
    return time.perf_counter() - t


p = argparse.ArgumentParser()
p.add_argument("--floor", type=int, default=1)
args = p.parse_args()
took = min(work() for _ in range(5))
factor = took / NATIVE
slowdown = min(CEILING, max(args.floor, math.ceil(0.75 * factor)))
print(f"slowdown: interpreter work takes {factor:.1f}x its native time here "
      f"({took:.3f} s vs {NATIVE} s): protocol times stretched {slowdown}x", file=sys.stderr)
print(slowdown)
