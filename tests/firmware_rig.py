"""A simulated Dynamixel bench whose detector is the emulated board (the firmware on simavr), in a process of its
own, for tests/test_firmware_faults.py: in the test's own interpreter the Dynamixel port would share the GIL with
the capture, and the Dynamixel SDK's wall-clock reply deadline misses on a loaded machine.

    python tests/firmware_rig.py CONFIG ELF BUILD_DIR FAULT AT

prints one JSON line of ports ``{"dynamixel": PATH, "serial": PATH}``. FAULT (``reset``, ``unplug``, ``freeze``,
``noise`` or ``none``) strikes the board at the first repeat of its reading number AT (darks and the white
reference count). stdin lines: ``plug`` (a new board; prints ``{"serial": PATH}``), ``thaw`` (the hung board runs
again and is reset, as an operator power-cycles it), ``angles`` (prints ``[theta_i, theta_o]``), ``quit``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from simulator.bench import VirtualBench  # noqa: E402
from simulator.config import load_config  # noqa: E402
from simulator.devices import firmware as fw  # noqa: E402
from simulator.ports.transports import PtyServer  # noqa: E402

FAULTS = {"reset": lambda b: b.reset(), "unplug": lambda b: b.unplug(), "freeze": lambda b: b.freeze(True),
          "noise": lambda b: b.noise(b"\x15\xfe~#garbage\xff\r\n"), "none": None}


def main() -> int:
    config, elf, build_dir, fault, at = sys.argv[1:6]
    bench = VirtualBench(load_config(config))
    bench.physics.warm_up()
    server = PtyServer(bench, names=("dynamixel",))
    boards: list[fw.EmulatedBoard] = []
    count = {"readings": 0}

    def plug(strike) -> str:
        board, feed = fw.start_firmware_detector(bench, Path(elf), build_dir=Path(build_dir))
        boards.append(board)

        def on_sync(ev: fw.SyncEvent):
            if ev.first and strike is not None:
                count["readings"] += 1
                if count["readings"] == int(at):
                    strike(board)
            return feed(ev)

        board.on_sync = on_sync
        return board.port

    print(json.dumps({"dynamixel": server.paths()["dynamixel"], "serial": plug(FAULTS[fault])}), flush=True)
    try:
        for line in sys.stdin:
            cmd = line.strip()
            if cmd == "plug":
                print(json.dumps({"serial": plug(None)}), flush=True)
            elif cmd == "thaw":
                boards[-1].freeze(False)
                boards[-1].reset()
                print("{}", flush=True)
            elif cmd == "angles":
                with bench.lock:
                    print(json.dumps(list(bench.arm_angles())), flush=True)
            elif cmd == "quit":
                break
    finally:
        for b in boards:
            b.close()
        server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
