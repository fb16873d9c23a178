"""Round-trip time of a GroupSyncRead of two servos through the pty of `gonio-sim serve`.

Usage: python benchmarks/bench_syncread.py [--config configs/simulated.toml] [-n 500]

Starts `gonio-sim serve` as a child process (so the simulator does not compete for this process' GIL), opens the
Dynamixel pty with the real dynamixel_sdk.PortHandler and times n GroupSyncRead transactions of Present Position
(address 132, 4 bytes) of the light and detector servos. Prints median, p99 and max in milliseconds.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, PacketHandler, PortHandler

REPO = Path(__file__).resolve().parents[1]


def percentile(xs: list[float], q: float) -> float:
    s = sorted(xs)
    k = min(len(s) - 1, max(0, round(q / 100 * (len(s) - 1))))
    return s[k]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default=str(REPO / "configs" / "simulated.toml"))
    ap.add_argument("-n", type=int, default=500, help="number of transactions (default 500)")
    args = ap.parse_args()

    proc = subprocess.Popen([sys.executable, "-m", "simulator.cli", "serve", "--config", args.config,
                             "--log-level", "warning", "--exit-with-parent"],
                            cwd=REPO, stdout=subprocess.PIPE, stdin=subprocess.DEVNULL)
    try:
        ports = json.loads(proc.stdout.readline())
        port = PortHandler(ports["dynamixel"])
        if not port.openPort():
            print("cannot open", ports["dynamixel"], file=sys.stderr)
            return 1
        ph = PacketHandler(2.0)
        ids = [1, 2]
        sr = GroupSyncRead(port, ph, 132, 4)
        for i in ids:
            sr.addParam(i)
        for _ in range(20):  # warm-up
            sr.txRxPacket()
        rtts, failures = [], 0
        for _ in range(args.n):
            t0 = time.perf_counter()
            res = sr.txRxPacket()
            dt = (time.perf_counter() - t0) * 1000.0
            if res != COMM_SUCCESS:
                failures += 1
                continue
            rtts.append(dt)
        single = []
        for _ in range(min(args.n, 200)):
            t0 = time.perf_counter()
            ph.read4ByteTxRx(port, 1, 132)
            single.append((time.perf_counter() - t0) * 1000.0)
        port.closePort()
        print(f"GroupSyncRead of {len(ids)} servos (Present Position) through {ports['dynamixel']}:")
        print(f"  transactions {args.n}, failures {failures}")
        if rtts:
            print(f"  median {statistics.median(rtts):.3f} ms   p99 {percentile(rtts, 99):.3f} ms   "
                  f"max {max(rtts):.3f} ms")
        print(f"single read4ByteTxRx: median {statistics.median(single):.3f} ms   "
              f"p99 {percentile(single, 99):.3f} ms")
        return 0 if not failures else 1
    finally:
        proc.terminate()
        proc.wait(10)


if __name__ == "__main__":
    sys.exit(main())
