"""Every file format of the project, declared once as msgspec structs: the bench file with the simulator's
sections (:mod:`.bench`, :mod:`.simulator`), scene files (:mod:`.scene`), materials (:mod:`.material`) and the slice
file's metadata (:mod:`.slice_meta`). :mod:`.core` reads TOML tables against them with messages that name the file,
the key path and what was expected; ``python scripts/write_schemas.py`` writes their JSON Schema to
``docs/schema/*.json`` for editors.

This is the base layer: acquisition, the simulator and the reconstruction all read their files through it.
"""

from reconstruction.schema.core import SchemaError, Table, describe, json_schema, read_table

__all__ = ["SchemaError", "Table", "describe", "json_schema", "read_table"]
