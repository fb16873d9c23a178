"""A capture procedure of one's own: re-read the white reference every N points (a source that drifts).

    python examples/reference_every_n.py [CONFIG] [OUT_DIR] [N]

A capture is a plan, a generator of messages that the engine runs (acquisition.plans); the plan that measures
the points can be replaced. This one is the default (acquisition.plans.measure_points) plus two lines: every N
points it reads the white reference again, and the engine converts with that reading from then on. Defaults:
configs/simulated.toml, out/reference-every-n, N = 10.
"""

from __future__ import annotations

import sys

from acquisition import Bench, plans
from acquisition.plans.geometry import point_key
from acquisition.plans.ordering import order_points


def reference_every(n: int) -> plans.PointsPlan:
    """A points plan that reads the white reference again before every ``n``-th point."""

    def points_plan(ctx: plans.CaptureContext, points: list) -> plans.PlanGen:
        todo = order_points([p for p in points if point_key(p) not in ctx.done], ctx.geometry)
        for k, (ti, to) in enumerate(todo):
            if k and k % n == 0:
                yield from plans.rereference(ctx.cfg)
            ctx.done[point_key((ti, to))] = yield from plans.point(ti, to, ctx.plan.repeats)

    return points_plan


def main() -> int:
    config = sys.argv[1] if len(sys.argv) > 1 else "configs/simulated.toml"
    out = sys.argv[2] if len(sys.argv) > 2 else "out/reference-every-n"
    n = int(sys.argv[3]) if len(sys.argv) > 3 else 10
    with Bench.from_config(config) as bench:
        result = bench.capture(out=out, points_plan=reference_every(n), progress=False)
    print(result.message)
    return result.exit_code


if __name__ == "__main__":
    sys.exit(main())
