"""Stress: in-process service (hw_axes_fast), AZ 260 <-> -80 at full speed with a watcher
polling; count drive faults and re-anchors. argv: tests dir, moves."""
import asyncio, sys, tempfile, time, logging
from pathlib import Path
tests = Path(sys.argv[1]); sys.path.insert(0, str(tests))
from support.live import LiveService
from support.opentci_client import Client
moves = int(sys.argv[2])
HW = tests / "hw_axes_fast.toml"
faults = []
class H(logging.Handler):
    def emit(self, rec):
        m = rec.getMessage()
        if "error code" in m or "following error" in m.lower() or "re-anchored" in m or "dropped" in m:
            faults.append(f"{time.monotonic():.3f} {rec.name} {m}")
logging.getLogger().addHandler(H()); logging.getLogger().setLevel(logging.INFO); logging.getLogger("tcs.drivers.cycle").setLevel(logging.DEBUG)

async def ready(c):
    await c.set("CABINET.POWER=1", 60)
    await c.set("ACKNOWLEDGE=1" if False else "AZ.ERROR_STATE=0", 30) if False else None
    await c.set("AZ.POWER=1", 30)
    if float(await c.value("AZ.REFERENCED")) < 1:
        await c.set("AZ.REINIT=1", 30)
        await c.wait("AZ.REFERENCED", lambda v: float(v) == 1.0, 60)

async def main(live):
    c = await Client.connect(live.port); w = await Client.connect(live.port)
    await ready(c)
    bad = 0
    for i in range(moves):
        target = (260, -80, 150)[i % 3]
        task = asyncio.ensure_future(c.set(f"AZ.TARGETPOS={target}", 60))
        while not task.done():
            await w.value("AZ.REALPOS")
        lines = await task
        if not lines[-1].endswith("COMPLETE") or any("ERROR" in x for x in lines):
            bad += 1
            print("FAILED", target, lines[-3:], flush=True)
            sim = live.telescope.sims[1]
            tg = list(sim.csp_targets)[-60:]
            t_end = tg[-1][0] if tg else 0
            print("csp_targets (t rel, target, continuous):")
            prev = None
            for t_, x, cont in tg:
                print(f"   {t_:.3f} {t_-t_end:+.3f} {x:.4f} {'' if prev is None else f'{x-prev:+.4f}'} {cont}")
                prev = x
            for m in faults[-15:]:
                print("  >", m[:300])
            await asyncio.sleep(1)
            await c.set("CABINET.ERROR_STATE=0", 30)
            await c.set("AZ.ERROR_STATE=0", 30)
            await ready(c)
    print("moves", moves, "failed", bad)
    await c.close(); await w.close()

live = LiveService(HW, Path(tempfile.mkdtemp()) / "state").start()
try:
    asyncio.run(main(live))
    st = live.telescope.cabinet.loop_stats()
    print({k: st[k] for k in ("cycles", "late", "missed", "max_lateness")})
    ax = live.telescope.axis("AZ")
    print("resumes", getattr(ax, "resumes", None))
    for m in faults:
        print(" ", m[:400])
    print("re-anchors logged", sum("re-anchored" in m for m in faults))
finally:
    live.stop()
