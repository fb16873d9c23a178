"""The scene file (``configs/scenes/*.toml``), declared once: what a reconstruction is for. Read by
:mod:`reconstruction.core.scene` (its keys come from here). Angles in degrees."""

from typing import Annotated, Literal

import msgspec
from msgspec import Meta

__all__ = ["LOBE_KINDS", "ErrorBudget", "SceneTable", "SceneFile"]

#: Lobe kinds a scene may allow (the fit's vocabulary; ``fresnel`` allows Schlick Fresnel on microfacet lobes).
LOBE_KINDS = ("lambert", "ggx", "beckmann", "retro", "fresnel")

Range = Annotated[tuple[Annotated[float, Meta(ge=0.0, lt=90.0)], Annotated[float, Meta(ge=0.0, lt=90.0)]], Meta(
    description="[min, max] degrees with 0 <= min <= max < 90")]
Positive = Annotated[float, Meta(gt=0.0)]


class ErrorBudget(msgspec.Struct, forbid_unknown_fields=True):
    """``[scene.error_budget]``."""

    relative_rmse: Annotated[Positive, Meta(description="relative RMSE of f cos cos the scene tolerates: the "
                                                        "simplest fit within it is used")] | None = None
    relative_sigma: Annotated[Positive, Meta(description="relative uncertainty added to the samples' std in the "
                                                         "fit's weights")] | None = None


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


class SceneFile(msgspec.Struct, forbid_unknown_fields=True):
    """A scene file: only ``[scene]``."""

    scene: SceneTable


def keys(cls: type) -> tuple[str, ...]:
    """The keys of a table of the schema, in declaration order."""
    return tuple(f.encode_name for f in msgspec.structs.fields(cls))
