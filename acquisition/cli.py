"""``gonio-capture``: drive the bench and capture an in-plane BRDF slice.

``gonio-capture --config CONFIG --out DIR [--resume [--force]]`` validates the bench file and the plan (nothing
moves before that succeeds), then captures into ``DIR/slice.csv`` (with its metadata), logging to
``DIR/capture.log``. A resume first measures the last recorded points again: another sample on the bench stops it
(``--force`` goes on, recorded in ``DIR/capture.json``).

Exit status: 0 complete; 1 stopped by a hardware or communication failure or a full disk (arms made safe,
resumable); 2 bad config, plan or output directory, or the directory is in use by another capture (nothing
moved), or a resume that found another sample on the bench; 130 / 143 interrupted by SIGINT / SIGTERM
(resumable). Every failure is reported without a traceback.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
import warnings
from pathlib import Path
from typing import Any

#: 2-opt budget of the time estimate that ``--check`` prints (the capture uses plan.TWO_OPT_MAX_EVALUATIONS).
CHECK_TWO_OPT_EVALUATIONS = 500_000

EPILOG = """\
examples:
  gonio-capture --config configs/simulated.toml --out out/demo
  gonio-capture --config configs/simulated.toml --out out/demo --resume
  gonio-capture --config configs/simulated.toml --out out/demo --live    # watch it at the URL printed
  gonio-capture --config configs/simulated.toml --out out/demo --resume --force   # another sample, on purpose
  gonio-capture --config configs/simulated.toml --out out/paint --scene configs/scenes/glossy-product.toml
  gonio-capture --config configs/dynamixel-bench.toml --check
  gonio-capture --config configs/mirror-misaligned.toml --align     # = gonio-align --config ...

exit status: 0 complete, 1 stopped by a hardware/communication fault or a full disk (resumable), 2 bad
config/plan, output folder not writable or in use by another capture (nothing moved), or a resume whose last
points, measured again, do not read as recorded (another sample: --resume --force goes on), 130/143 interrupted
by SIGINT/SIGTERM (resumable with --resume).
"""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="gonio-capture",
        description="Capture an in-plane BRDF slice on a gonioreflectometer (Dynamixel servos, a stepper "
                    "controller, or the simulator) into DIR/slice.csv; checkpointed and resumable.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", required=True, help="bench file (TOML), e.g. configs/simulated.toml")
    p.add_argument("--out", metavar="DIR", help="output directory: slice.csv, capture.log, capture.json")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted capture in --out (measured samples are kept and skipped)")
    p.add_argument("--force", action="store_true",
                   help="with --resume: go on although the last recorded points, measured again first, do not read "
                        "as recorded (another sample on purpose; recorded in capture.json)")
    p.add_argument("--unlock", action="store_true",
                   help="GRBL bench in alarm without switches: unlock it ($X) on purpose for this run; you checked "
                        "the arms are where GRBL believes them ([motion.grbl].unlock for one run)")
    p.add_argument("--scene", help="scene file the plan is fitted to (configs/scenes/*.toml): its ranges limit the "
                                   "plan, its angular resolution sets the step (a finer one adds points)")
    p.add_argument("--check", action="store_true",
                   help="validate the config (on a simulated bench also its [simulator] sections, through "
                        "`gonio-sim check`) and the plan, print the points and time estimate, move nothing")
    prog = p.add_mutually_exclusive_group()
    prog.add_argument("--progress", dest="progress", action="store_true", default=None,
                      help="always show the progress bar (default: only on a terminal)")
    prog.add_argument("--no-progress", dest="progress", action="store_false", help="never show it")
    p.add_argument("--live", action="store_true",
                   help="serve a live view of the capture (the slice as it grows, the time left, the last sample) "
                        "on http://127.0.0.1:PORT/ while it runs; the URL is printed when it starts")
    p.add_argument("--live-port", type=int, metavar="PORT", help="the live view's port (default: a free one)")
    p.add_argument("--live-host", metavar="ADDRESS",
                   help="serve the live view on this address instead of 127.0.0.1 (reachable from the network: "
                        "on purpose only)")
    p.add_argument("--align", action="store_true",
                   help="align the bench instead of capturing: `gonio-align --config CONFIG` (a mirror as the "
                        "sample; see gonio-align --help for its options)")
    p.add_argument("--live-allow-host", action="append", default=[], metavar="NAME",
                   help="a host name the live view may be reached by (repeatable), beside localhost, IP addresses "
                        "and --live-host; any other Host is refused (a page elsewhere cannot read it by DNS "
                        "rebinding)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object on stdout")
    p.add_argument("--log-level", default="warning", choices=("debug", "info", "warning", "error"),
                   help="stderr log level (the log file always gets info)")
    return p


class _BarSafeHandler(logging.StreamHandler):  # type: ignore[type-arg]
    """Console log handler that writes through tqdm, so messages do not tear the progress bar."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            from tqdm import tqdm

            tqdm.write(self.format(record), file=self.stream)
        except Exception:  # pragma: no cover
            self.handleError(record)


def main(argv: list[str] | None = None, *, process: bool | None = None) -> int:
    """Entry point of the ``gonio-capture`` console script. ``process``: this call is the whole process (the
    default when ``argv`` is None: the console script and ``python -m acquisition.cli``), so once a signal stopped
    the capture a second one is ignored until the process exits; an in-process caller (``argv`` given) gets its
    signal handlers back when main returns."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.force and not args.resume:
        parser.error("--force goes with --resume (it accepts another sample in a capture being resumed)")
    if args.align:
        from acquisition.align import main as align_main

        return align_main(["--config", args.config] + (["--json"] if args.json else []))
    from acquisition.run.interrupts import SignalGuard

    # once a signal stopped the capture this run ends: a second one while it prints where to resume, or in the
    # instant before the process exits, is ignored (SignalGuard.__exit__); an in-process caller gets the handlers
    # of before back when main returns (its later children must not inherit an ignored SIGTERM)
    whole_process = argv is None if process is None else process
    SignalGuard.ignore_after_signal = True
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    handler = _BarSafeHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("gonio-capture: %(levelname)s: %(message)s"))
    handler.setLevel(getattr(logging, args.log_level.upper()))
    handler.addFilter(lambda rec: not getattr(rec, "final", False))  # the final message is printed below
    lg = logging.getLogger("acquisition")
    lg.addHandler(handler)
    lg.setLevel(logging.DEBUG if args.log_level == "debug" else logging.INFO)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # numpy's: never shown to an operator
            return _run(args)
    except KeyboardInterrupt:  # Ctrl-C before the capture's own signal handling is in place
        print("gonio-capture: interrupted; nothing was moved", file=sys.stderr)
        return 130
    except OSError as e:  # an output file that cannot be written outside the capture's own handling
        where = f"{e.filename}: " if e.filename else ""
        print(f"gonio-capture: {where}{e.strerror or e}", file=sys.stderr)
        return 1
    finally:
        lg.removeHandler(handler)
        SignalGuard.ignore_after_signal = False
        if not whole_process and threading.current_thread() is threading.main_thread():
            for sig, h in before.items():
                if h is not None:
                    signal.signal(sig, h)


def _duration(seconds: float) -> str:
    """``seconds`` for a person: 41.2 s, 12.5 min, 3.2 h, 4.1 days."""
    if seconds < 120:
        return f"{seconds:.2f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    if seconds < 3 * 86400:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


def _time_summary(r: Any, time_scale: float = 0.0) -> str:
    """Estimate and bench time of a capture side by side (two lines, indented; a third on a simulator running
    faster than real time, ``time_scale`` > 1, whose bench time magnifies the software's own wall time)."""
    clock = "simulated " if r.bench_clock == "controller" else ""
    est = r.estimate_s + r.estimate_refinement_s
    dev = f" ({100.0 * (est - r.bench_time_s) / r.bench_time_s:+.1f} %)" if r.bench_time_s > 0 else ""
    refine = f", of which refinement rounds {r.estimate_refinement_s:.2f} s" if r.estimate_refinement_s else ""
    other = max(r.bench_time_s - r.motion_s - r.settle_s - r.read_s, 0.0)
    e = r.estimate
    return (f"  {clock}capture time {r.bench_time_s:.2f} s of bench time, estimated {est:.2f} s{dev}{refine}; "
            f"wall clock {r.wall_s:.2f} s\n"
            f"  actual (estimate): moving {r.motion_s:.2f} s ({e.get('motion_s', r.plan_motion_estimate_s):.2f} s; "
            f"{r.naive_motion_estimate_s:.2f} s in naive order), settling {r.settle_s:.2f} s "
            f"({e.get('settle_s', 0.0):.2f} s), detector {r.read_s:.2f} s ({e.get('read_s', 0.0):.2f} s), darks "
            f"and white reference {other:.2f} s ({e.get('calibration_s', 0.0):.2f} s)"
            + (f"\n  at [simulator].time_scale = {time_scale:g} the software's own wall time (its commands, polls and "
               f"file writes) counts {time_scale:g} times over as bench time, beyond what the estimate models for a "
               "real bench: the capture takes longer than estimated (docs/capture.md, Capture time: one model)"
               if time_scale > 1 and r.bench_clock == "controller" else ""))


def _start_live(args: argparse.Namespace) -> Any:
    """The live view of ``--live`` (``--live-port``/``--live-host`` imply it), started in a child process: its URL is
    printed; one that cannot start is a warning, and the capture goes on."""
    if not (args.live or args.live_port is not None or args.live_host):
        return None
    from acquisition.live import LiveView

    view = LiveView(args.out, args.live_host or "127.0.0.1", args.live_port or 0, tuple(args.live_allow_host))
    url = view.start()
    if url is None:
        return None
    where = "" if (args.live_host or "127.0.0.1") in ("127.0.0.1", "localhost", "::1") else \
        f" (on {args.live_host}: reachable from the network)"
    print(f"gonio-capture: live view at {url}{where}; it ends with the capture", file=sys.stderr, flush=True)
    return view


def _print_check(args: argparse.Namespace, bench: Any, plan: Any, chk: Any, est: dict[str, Any]) -> None:
    """What --check prints: the scene's changes, the plan's check, the ports, the footprint and the estimate."""
    from acquisition.plans.planconfig import MAX_PLAN_POINTS

    if args.scene:
        from acquisition.plans.plan import scene_changes

        print(scene_changes(bench.plan(), plan))
    print(chk.describe(limit=1000))
    from acquisition.optics import footprint_warning
    from acquisition.ports import describe_ports

    print("\n".join(describe_ports(bench.cfg)) or "ports: the simulator's, made when a capture starts")

    warn = footprint_warning(bench.cfg, [p[0] for p in chk.measurable])
    if warn:
        print(f"warning: {warn}")
    grows = " (before adaptive refinement, which may add up to " \
            f"{plan.size() - len(chk.measurable) - len(chk.unmeasurable):.0f})" if plan.adaptive else ""
    print(f"plan size: {len(chk.measurable) + len(chk.unmeasurable)} points{grows}, limit {MAX_PLAN_POINTS}")
    refine = " before adaptive refinement (its rounds are estimated as they are planned)" if plan.adaptive else ""
    print(f"estimated bench time: {est['total_s']:.2f} s in all{refine}"
          + (f" ({_duration(est['total_s'])})" if est["total_s"] >= 120 else "")
          + f" = motion {est['motion_s']:.2f} s (arm travel in plan order; {est['naive_motion_s']:.2f} s in "
            f"naive order) + settling {est['settle_s']:.2f} s + detector integration {est['read_s']:.2f} s + "
            f"darks and white reference {est['calibration_s']:.2f} s; then parking {est['park_s']:.2f} s")


def _run(args: argparse.Namespace) -> int:
    from acquisition.bench import Bench, SimulatorCheck
    from acquisition.devices import grbl_settings
    from acquisition.errors import CommError, ConfigError, PlanError
    from acquisition.run.dryrun import estimate
    from acquisition.run.lock import OutDirLocked
    from acquisition.run.outdir import out_dir_problem
    from acquisition.run.record import result_dict

    sim_check = None
    try:
        bench = Bench.from_config(args.config)
        if args.unlock:
            bench.cfg.motion = grbl_settings.unlocked(bench.cfg)
        if args.check and bench.cfg.bench.transport == "simulated":
            # the [simulator] sections, as `gonio-sim serve` reads them, checked while the plan is
            sim_check = SimulatorCheck(bench.cfg.path, bench.cfg.bench.simulator_command)
        plan = bench.plan(scene=args.scene)
        try:
            chk = plan.validate(bench.geometry)
        except PlanError as e:  # the plan and the bench disagree: say which file
            where = f"--scene {args.scene} with " if args.scene else ""
            raise PlanError(f"{where}{bench.cfg.path}: [plan]: {e}") from None
    except (ConfigError, PlanError) as e:
        if sim_check is not None:
            sim_check.cancel()
        print(f"gonio-capture: {e}; nothing was moved", file=sys.stderr)
        return 2
    except CommError as e:
        print(f"gonio-capture: {e}", file=sys.stderr)
        return 1
    if args.check:
        # a quicker 2-opt than the capture's own: the same order up to ~1000 points, and --check stays < 1 s
        est = estimate(plan, bench.geometry, bench.cfg.detector.integration_time_s, chk.measurable,
                       max_evaluations=CHECK_TWO_OPT_EVALUATIONS, cfg=bench.cfg)
        if sim_check is not None:
            try:
                sim_check.result()
            except ConfigError as e:
                print(f"gonio-capture: {e}; nothing was moved", file=sys.stderr)
                return 2
            except CommError as e:
                print(f"gonio-capture: {e}", file=sys.stderr)
                return 1
        if not bench.cfg.detector.on_board and bench.cfg.bench.transport != "simulated":
            from acquisition.devices.external import check_external_library

            try:  # the detector's library (seabreeze; pyvisa and a VISA library) is installed: the capture needs it
                check_external_library(bench.cfg)
            except ConfigError as e:
                print(f"gonio-capture: {e}; nothing was moved", file=sys.stderr)
                return 2
        _print_check(args, bench, plan, chk, est)
        return 0
    if not args.out:
        print("gonio-capture: --out DIR is required to capture (or use --check)", file=sys.stderr)
        return 2
    created = not Path(args.out).exists()
    try:
        Path(args.out).mkdir(parents=True, exist_ok=True)
    except OSError as e:
        print(f"gonio-capture: --out {out_dir_problem(Path(args.out), e)}", file=sys.stderr)
        return 2
    view = _start_live(args)
    try:
        result = bench.capture(plan, out=Path(args.out), resume=args.resume, progress=args.progress,
                               force=args.force, live=view is not None)
    except OutDirLocked as e:  # one line: the folder and the PID holding it
        print(f"gonio-capture: {e}", file=sys.stderr)
        return 2
    except (ConfigError, PlanError) as e:
        print(f"gonio-capture: {e}; nothing was moved", file=sys.stderr)
        return 2
    finally:
        if view is not None:
            view.stop()  # the live view ends with the capture
        if created and not any(Path(args.out).iterdir()):  # a folder made for a run that wrote nothing
            Path(args.out).rmdir()
    if args.json:
        print(json.dumps(result_dict(result), sort_keys=True))
    if result.ok and result.exit_code == 0:
        if not args.json and result.samples_new == 0 and "already complete" in result.message:
            print(f"gonio-capture: {result.message}", file=sys.stderr)
        elif not args.json:
            extra = ""
            if result.unmeasurable:
                extra = (f"; {len(result.unmeasurable)} plan point(s) not measurable (collision / blind spot), "
                         f"listed in {Path(args.out) / 'capture.log'}")
            ranged = ""
            if result.auto_ranged:
                from acquisition.devices.autorange import ranged_wording

                settings = "; ".join(f"{k}{'' if 'gain' in k else ' s'}: {v}"
                                     for k, v in result.auto_range_settings.items())
                what = ranged_wording(result.auto_range_settings, bench.cfg.detector.integration_time_s)
                count = f"{result.auto_ranged} point(s)"
                if result.samples_total > result.samples_new:  # a resume: this run's, then the capture's
                    count = (f"{result.auto_ranged_new} of this run's {result.samples_new} point(s) "
                             f"({result.auto_ranged} of the capture's {result.samples_total})")
                ranged = (f"\n  auto-ranged {count}, read {what} ({settings});"
                          f" {result.auto_range_overhead_s:.2f} s of extra integration in this run")
            from acquisition.plans.geometry import _simulator_timing

            scale = (_simulator_timing(bench.cfg) or {}).get("time_scale", 0.0)
            print(f"gonio-capture: {result.message}{extra}\n{_time_summary(result, scale)}{ranged}", file=sys.stderr)
        return 0
    print(f"gonio-capture: {result.message}", file=sys.stderr)
    return result.exit_code or 1


if __name__ == "__main__":
    sys.exit(main())
