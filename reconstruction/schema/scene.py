"""The scene file (``configs/scenes/*.toml``), declared once: what a reconstruction is for. Read by
:mod:`reconstruction.core.scene` (its keys come from here). Angles in degrees."""

from typing import Annotated, Literal

import msgspec
from msgspec import Meta

__all__ = ["LOBE_KINDS", "GEOMETRIES", "ErrorBudget", "View", "SceneTable", "SceneFile"]

#: Lobe kinds a scene may allow (the fit's vocabulary; ``fresnel`` allows Schlick Fresnel on microfacet lobes).
LOBE_KINDS = ("lambert", "ggx", "beckmann", "retro", "fresnel")
#: What a renderer shows of the material: a whole object (every normal facing the camera), or a flat sample.
GEOMETRIES = ("sphere", "plane")

Range = Annotated[tuple[Annotated[float, Meta(ge=0.0, lt=90.0)], Annotated[float, Meta(ge=0.0, lt=90.0)]], Meta(
    description="[min, max] degrees with 0 <= min <= max < 90")]
Positive = Annotated[float, Meta(gt=0.0)]


class ErrorBudget(msgspec.Struct, forbid_unknown_fields=True):
    """``[scene.error_budget]``."""

    relative_rmse: Annotated[Positive, Meta(description="relative RMSE of f cos cos the scene tolerates: the "
                                                        "simplest fit within it is used")] | None = None
    relative_sigma: Annotated[Positive, Meta(description="relative uncertainty added to the samples' std in the "
                                                         "fit's weights")] | None = None


class View(msgspec.Struct, forbid_unknown_fields=True):
    """``[scene.view]``: what a renderer will do, instead of angle ranges: the geometry, the camera and the lights;
    the scene's theta_i and theta_o ranges follow from it (where the file gives none)."""

    geometry: Annotated[Literal[GEOMETRIES], Meta(  # type: ignore[valid-type]
        description="sphere: an object seen whole (every normal facing the camera); plane: a flat sample")] = "sphere"
    camera_deg: Annotated[list[Annotated[float, Meta(ge=0.0, lt=90.0)]], Meta(
        min_length=1, description="plane: the camera's polar angles from the normal (degrees); sphere: unused")
    ] | None = None
    lights_deg: Annotated[list[tuple[float, float]], Meta(
        min_length=1, description="light directions [polar, azimuth] in degrees: plane: from the normal, azimuth "
                                  "from the camera's (180: the mirror side); sphere: the angle from the camera's "
                                  "direction and the azimuth about it")] | None = None
    coverage: Annotated[float, Meta(gt=0.0, le=1.0, description="sphere: the share of the lit, seen surface "
                                                                 "(weighted by cos theta_i) the ranges keep")] = 0.9


class SceneTable(msgspec.Struct, forbid_unknown_fields=True):
    """``[scene]``: the ranges, the angular resolution, the lobes and the error budget a scene needs."""

    name: Annotated[str, Meta(description="default: the file name")] | None = None
    theta_i_deg: Range | None = None
    theta_o_deg: Annotated[Range, Meta(description="polar angles |theta_o|, both sides of the normal")] | None = None
    angular_resolution_deg: Annotated[Positive, Meta(
        description="finest detail that matters (degrees): the capture's step, the fit's smallest alpha"
    )] | None = None
    lobes: Annotated[list[Literal[LOBE_KINDS]], Meta(min_length=1)] | None = None  # type: ignore[valid-type]
    error_budget: ErrorBudget | None = None
    view: View | None = None


class SceneFile(msgspec.Struct, forbid_unknown_fields=True):
    """A scene file: only ``[scene]``."""

    scene: SceneTable


def keys(cls: type) -> tuple[str, ...]:
    """The keys of a table of the schema, in declaration order."""
    return tuple(f.encode_name for f in msgspec.structs.fields(cls))
