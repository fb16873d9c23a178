"""``python -m acquisition.live --dir DIR [--host H] [--port P] [--parent PID] [--allow-host NAME]...``: serve the
live view of the capture in DIR until SIGTERM/SIGINT or until the process PID (the capture) is gone. The first
line on stdout is JSON, ``{"url": "http://127.0.0.1:PORT/"}``; a server that cannot start prints
one line on stderr and exits 2."""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m acquisition.live", description=__doc__)
    p.add_argument("--dir", required=True, help="the capture's folder")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=0, help="0: a free port")
    p.add_argument("--parent", type=int, default=0, help="exit when this process is gone")
    p.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                   help="a host name the page may be reached by, beside localhost and the bound name (repeatable)")
    args = p.parse_args(argv)
    try:
        os.nice(10)  # the capture comes first
    except OSError:  # pragma: no cover
        pass
    from acquisition.live.server import LiveServer

    try:
        srv = LiveServer(args.dir, args.host, args.port, tuple(args.allow_host))
    except (OSError, OverflowError, ValueError) as e:
        print(f"live view: cannot serve on {args.host}:{args.port}: {e}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.2}, daemon=True).start()
    print(json.dumps({"url": srv.url}), flush=True)
    while not stop.wait(0.5):
        if args.parent and os.getppid() != args.parent:
            break
    srv.shutdown()
    srv.server_close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
