"""``gonio-sim``: run the virtual gonioreflectometer.

``gonio-sim serve --config configs/simulated.toml`` starts the bench on pseudo-terminals, prints one JSON line
with the port paths on stdout (``{"dynamixel": "/dev/pts/5", "serial": "/dev/pts/6"}``; ``dynamixel`` is null on
a stepper bench) and serves until SIGINT/SIGTERM, then exits 0. Logs go to stderr.

``gonio-sim check --config FILE`` validates the file as ``serve`` would (without opening any port): one line on
stdout and exit status 0 when it is fine, else one line naming the file and the key on stderr and exit status 2
(which is also ``serve``'s status for a bad config). ``gonio-capture --check`` runs it for simulated benches.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
import time

log = logging.getLogger("simulator")

EPILOG = """\
examples:
  gonio-sim serve --config configs/simulated.toml
  gonio-sim serve --config configs/simulated.toml --seed 7 --time-scale 0 --log-level debug
  gonio-sim check --config configs/simulated.toml

protocols:
  dynamixel port: Dynamixel Protocol 2.0 (X-series control table), open with dynamixel_sdk.PortHandler
  serial port:    text protocol of docs/serial-protocol.md (detector; axes on a stepper bench), 115200 8N1
  usb port:       [detector] type = "seabreeze" or "pm100" only: their world, for the test suite's stand-ins of
                  python-seabreeze and pyvisa (simulator/devices/usb_detectors.py, docs/detectors.md)
  grbl port:      GRBL 1.1 (G-code, $ commands, realtime ? ! ~ 0x18) on a bench with motion = "grbl"
"""


def _attempt(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="gonio-sim",
        description="Virtual in-plane gonioreflectometer: Dynamixel servos or a stepper controller, a detector "
                    "and BRDF ground truth, served on pseudo-terminals for the real SDK and pyserial.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    s = sub.add_parser(
        "serve",
        help="start the virtual bench on pseudo-terminals and serve until SIGINT/SIGTERM",
        description="Start the virtual bench, print one JSON line {\"dynamixel\": PATH|null, \"serial\": PATH} "
                    "on stdout, serve until SIGINT/SIGTERM, then exit 0.",
    )
    s.add_argument("--config", required=True, help="bench config TOML (e.g. configs/simulated.toml)")
    s.add_argument("--seed", type=int, default=None, help="override [simulator].seed (noise and faults)")
    s.add_argument("--time-scale", type=float, default=None,
                   help="override [simulator].time_scale: 0 = as fast as possible, 1 = real time, "
                        "10 = ten times faster than real time")
    s.add_argument("--motion", choices=("dynamixel", "serial", "grbl"), default=None,
                   help="override [bench].motion: which virtual motion hardware to serve")
    s.add_argument("--detector-firmware", default=os.environ.get("GONIO_SIM_DETECTOR_FIRMWARE") or None,
                   metavar="ELF",
                   help="serve the detector with the real firmware (e.g. firmware/detector/build/detector.elf, "
                        "`make -C firmware/detector`) on an emulated ATmega328P (simavr): its UART is the serial "
                        "port, its ADC reads the physics (Dynamixel benches, time_scale 0). Default: "
                        "$GONIO_SIM_DETECTOR_FIRMWARE (so gonio-capture's simulated benches use it)")
    s.add_argument("--firmware-dither", type=float, default=0.5, metavar="LSB",
                   help="with --detector-firmware: rms noise of every ADC conversion, in counts (default 0.5)")
    s.add_argument("--arm-steps", default=None, metavar="FILE",
                   help="serve the detector only, the arms' angles read from grbl-sim's step output (-s FILE -r T; "
                        "with --arm-blocks, its -b FILE): the arms run on GRBL's own code")
    s.add_argument("--arm-blocks", default=None, metavar="FILE", help="grbl-sim's block output (-b FILE)")
    s.add_argument("--log-level", default="info", choices=("debug", "info", "warning", "error"),
                   help="stderr log level (default: info)")
    s.add_argument("--exit-with-parent", action="store_true",
                   help="exit when the parent process dies (for child processes of a capture)")
    s.add_argument("--attempt", type=_attempt, default=0, metavar="N",
                   help="the run of a resumed capture (0 = its first): noise and faults come from random streams "
                        "of their own, continuing rather than replaying the earlier runs' (default 0)")
    c = sub.add_parser(
        "check",
        help="validate a bench config as serve would, without opening any port",
        description="Validate the config as `gonio-sim serve` would ([simulator], [simulator.faults], "
                    "[simulator.spectrometer], the keys it reads from the other sections, the material), without "
                    "opening any port. Prints one line and exits 0 when the config is fine; otherwise prints one "
                    "line naming the file and the key and exits 2.",
    )
    c.add_argument("--config", required=True, help="bench config TOML (e.g. configs/simulated.toml)")
    b = sub.add_parser(
        "study", aliases=["bench"],
        help="run the speed/accuracy study: simulated captures x reconstruction methods ('bench' is its old name, "
             "still accepted)",
        description="Run simulated captures (gonio-capture against gonio-sim serve, simulated time as fast as "
                    "possible) over a grid of outgoing step, number of incidence slices, repeats, uniform vs "
                    "adaptive plans and noise, for several materials, reconstruct each with every method, and "
                    "write OUT/NAME.csv (every row), OUT/NAME-pareto.png and the NAME section of the study page "
                    "OUT/study.md (Pareto fronts, recommendations per error budget; the rest of the page is kept).",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n  gonio-sim study --quick\n  gonio-sim study --workers 2\n"
               "  gonio-sim study --scheduler tcp://10.0.0.5:8786   # run the cases on a Dask cluster\n"
               "  gonio-sim study --materials sharp-ggx,mirror --merge docs/study.csv --out docs",
    )
    b.add_argument("--quick", action="store_true", help="a small grid (4 settings x 6 materials), ~3-4 min")
    b.add_argument("--config", default="configs/simulated.toml",
                   help="base simulated bench file (default: configs/simulated.toml)")
    b.add_argument("--out", default="out/study",
                   help="where the CSV, the study page and the plot go (default: out/study, beside the captures; the "
                        "committed results are regenerated with --out docs)")
    b.add_argument("--name", default=None,
                   help="the study's name: its CSV and plot file stem and its section of study.md (default: "
                        "study-quick or study)")
    b.add_argument("--workdir", default="out/study", help="captures and per-case configs (default: out/study)")
    b.add_argument("--materials", default=None,
                   help="comma-separated subset of: diffuse, glossy-ggx, sharp-ggx, back-scatter, rough-oren-nayar, "
                        "mirror (or of the --material-dir names)")
    b.add_argument("--merge", default=None, metavar="CSV",
                   help="keep the rows of an earlier study CSV for the materials this run does not capture (e.g. "
                        "rerun two materials of docs/study.csv: --materials sharp-ggx,mirror --merge docs/study.csv "
                        "--out docs); the study page says which rows are kept")
    b.add_argument("--material-dir", default=None, metavar="DIR",
                   help="study the materials of DIR instead: every neural BRDF set NAME_fc1.npy ... NAME_b3.npy "
                        "(e.g. ../shared/realdata/nbrdf-merl) and every material TOML file; recommendations then "
                        "use rmse80 (cells with both angles <= 80 deg)")
    b.add_argument("--reduced", action="store_true",
                   help="a reduced grid: 1 and 4 slices, 2 deg steps, 4 repeats, uniform plan, low noise")
    b.add_argument("--scheduler", default=None,
                   help="dask.distributed scheduler address: run the cases on that cluster (pip install "
                        "'gonio-brdf[dask]')")
    b.add_argument("--workers", type=int, default=None, help="local worker processes (default: CPU count)")
    b.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def _bench(args: argparse.Namespace) -> int:
    from pathlib import Path

    from simulator.study import MATERIALS, grid, materials_from_dir, run_study

    if not Path(args.config).is_file():
        print(f"gonio-sim study: --config {args.config}: no such file", file=sys.stderr)
        return 2
    catalogue = MATERIALS
    if args.material_dir:
        try:
            catalogue = materials_from_dir(args.material_dir)
        except ValueError as e:
            print(f"gonio-sim study: --material-dir: {e}", file=sys.stderr)
            return 2
    try:
        cases = grid(args.quick, args.materials.split(",") if args.materials else None, catalogue, args.reduced)
    except ValueError as e:
        print(f"gonio-sim study: --materials: {e}", file=sys.stderr)
        return 2
    merge: list = []
    if args.merge:
        from simulator.study import read_rows

        try:
            merge = read_rows(args.merge)
        except ValueError as e:
            print(f"gonio-sim study: --merge: {e}", file=sys.stderr)
            return 2
    name = args.name or ("study-quick" if args.quick else "study")
    command = "gonio-sim study" + (" --quick" if args.quick else "") + (" --reduced" if args.reduced else "") + (
        f" --material-dir {args.material_dir}" if args.material_dir else "") + (
        f" --materials {args.materials}" if args.materials else "") + (f" --merge {args.merge}" if args.merge else "")
    from simulator.study import METHODS, estimate_seconds

    workers = args.workers or (os.cpu_count() or 1)
    est = estimate_seconds(cases, 1 if args.scheduler else workers)
    print(f"gonio-sim study: {len(cases)} captures x {len(METHODS)} methods; estimated "
          f"{est / 60:.0f} min" + ("" if args.scheduler else f" on {workers} local worker(s)")
          + f"; results to {args.out}", file=sys.stderr)
    t0 = time.perf_counter()
    try:
        rows = run_study(cases, args.config, args.workdir, args.out, name, command, args.scheduler, args.workers,
                         progress=not args.no_progress, catalogue=catalogue,
                         metric="rmse80" if args.material_dir else "rel_rmse_cos", merge=merge,
                         merge_source=args.merge or "")
    except RuntimeError as e:
        print(f"gonio-sim study: {e}", file=sys.stderr)
        return 2
    failed = sum(r.get("status") != "ok" for r in rows)
    print(f"gonio-sim study: {len(cases)} captures, {len(rows)} results ({failed} failed) in "
          f"{time.perf_counter() - t0:.0f} s; wrote {args.out}/{name}.csv, {name}-pareto.png and the {name} section of "
          "study.md")
    return 1 if failed == len(rows) else 0


def _load_bench(config: str, seed: int | None = None, time_scale: float | None = None,
                motion: str | None = None, attempt: int = 0, arm_files: tuple[str, str] | None = None):
    """(config, VirtualBench) for ``config``; raises ValueError with a message naming the file."""
    from simulator.bench import VirtualBench
    from simulator.config import load_config

    try:
        cfg = load_config(config, seed=seed, time_scale=time_scale)
        if motion:
            cfg.motion = motion
        track = None
        if arm_files is not None:
            from simulator.world.stepfile import GrblSimTrack

            track = GrblSimTrack(arm_files[0], arm_files[1], cfg.axes["light"], cfg.axes["detector"])
        return cfg, VirtualBench(cfg, attempt=attempt, arm_source=track)
    except (OSError, ValueError) as e:
        msg = str(e)
        if not msg.startswith(str(config)):
            msg = f"{config}: {msg}"
        raise ValueError(msg) from None


def _check(args: argparse.Namespace) -> int:
    try:
        cfg, _ = _load_bench(args.config)
    except ValueError as e:
        print(f"gonio-sim: {e}", file=sys.stderr)
        return 2
    name = cfg.material.get("name") or "unnamed"
    print(f"gonio-sim: {args.config}: ready to serve ({cfg.motion} motion, material {name!r}); nothing opened")
    return 0


def _serve(args: argparse.Namespace) -> int:
    from simulator.ports.transports import PtyServer

    if (args.arm_steps is None) != (args.arm_blocks is None):
        print("gonio-sim: --arm-steps and --arm-blocks go together (grbl-sim's -s and -b files)", file=sys.stderr)
        return 2
    arm_files = (args.arm_steps, args.arm_blocks) if args.arm_steps else None
    try:
        cfg, bench = _load_bench(args.config, args.seed, args.time_scale, args.motion, args.attempt, arm_files)
        bench.physics.warm_up()  # before the ports serve: a first reading within the reply deadline
    except ValueError as e:
        print(f"gonio-sim: {e}", file=sys.stderr)
        return 2

    stop = threading.Event()

    def _on_signal(signum, frame):
        stop.set()

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)

    board = None
    if args.detector_firmware:
        from simulator.devices.firmware import FirmwareError, start_firmware_detector

        try:
            board, _ = start_firmware_detector(bench, args.detector_firmware, dither_lsb=args.firmware_dither,
                                               seed=cfg.sim.seed + 7919 * args.attempt)
        except (FirmwareError, ValueError, OSError) as e:
            print(f"gonio-sim: --detector-firmware: {e}", file=sys.stderr)
            return 2
    server = PtyServer(bench, names=("dynamixel",) if board is not None else None)
    paths = server.paths()
    if board is not None:
        paths["serial"] = board.port
    try:
        print(json.dumps(paths), flush=True)
        log.info("serving %s: %s (motion=%s, detector=%s%s, seed=%d, attempt=%d, time_scale=%g)", cfg.bench.name,
                 paths, cfg.motion, cfg.detector.kind, f" on the firmware {args.detector_firmware}" if board else "",
                 cfg.sim.seed, args.attempt, cfg.sim.time_scale)
        parent = os.getppid()
        while not stop.wait(0.2):
            if args.exit_with_parent and os.getppid() != parent:
                log.info("parent process gone; exiting")
                break
    finally:
        server.close()
        if board is not None:
            board.close()
        log.info("stopped; total simulated time %.6f s; fault counts: dynamixel %s, serial %s, motion %s, "
                 "detector %s", bench.sim_time(), bench.dxl_comm_faults.counts, bench.serial_comm_faults.counts,
                 bench.motion_faults.counts, bench.detector_faults.counts)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``gonio-sim`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    if args.command in ("study", "bench"):
        logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
        return _bench(args)
    if args.command == "check":
        logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
        return _check(args)
    logging.basicConfig(level=getattr(logging, args.log_level.upper()), stream=sys.stderr,
                        format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    return _serve(args)


if __name__ == "__main__":
    sys.exit(main())
