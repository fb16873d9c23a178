"""Write the JSON Schema of every file format to docs/schema/ (for editors: a TOML editor with a JSON Schema
plugin, e.g. Taplo / Even Better TOML, then completes and checks bench, scene and material files).

    .venv/bin/python scripts/write_schemas.py [--out docs/schema] [--check]

The schemas come from the formats' declarations in reconstruction.schema (and the methods' options in
reconstruction.methods); --check only reports whether the files are up to date (exit status 1 if not).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def schemas() -> dict[str, dict[str, Any]]:
    """File name -> JSON Schema."""
    from reconstruction import methods
    from reconstruction.schema.bench import BenchFile
    from reconstruction.schema.core import json_schema
    from reconstruction.schema.material import MaterialFile
    from reconstruction.schema.scene import SceneFile
    from reconstruction.schema.slice_meta import SliceMeta

    return {
        "bench.json": json_schema(BenchFile, "gonio-brdf bench file",
                                  "A bench file (configs/*.toml): gonio-capture --config, gonio-sim serve --config."),
        "scene.json": json_schema(SceneFile, "gonio-brdf scene file",
                                  "A scene file (configs/scenes/*.toml): what a capture and a fit are for."),
        "material.json": json_schema(MaterialFile, "gonio-brdf material",
                                     "A material ([material] of a simulated bench, or a material file): a sum of "
                                     "lobes."),
        "slice-meta.json": json_schema(SliceMeta, "gonio-brdf slice metadata",
                                       "The '# meta:' JSON line of a slice file (docs/formats.md)."),
        "method-options.json": methods.options_schema(),
    }


def render(schema: dict[str, Any]) -> str:
    return json.dumps(schema, indent=2, sort_keys=True) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(REPO / "docs" / "schema"), help="folder (default: docs/schema)")
    ap.add_argument("--check", action="store_true", help="report stale files instead of writing them")
    args = ap.parse_args(argv)
    out = Path(args.out)
    stale = []
    for name, schema in schemas().items():
        path = out / name
        text = render(schema)
        if args.check:
            if not path.is_file() or path.read_text(encoding="utf-8") != text:
                stale.append(str(path))
            continue
        out.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
        print(f"wrote {path}")
    if stale:
        print("out of date (run scripts/write_schemas.py): " + ", ".join(stale), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
