"""Solids of revolution (Tramontina, TU Delft 2023): a full isotropic BRDF from in-plane slices.

The thesis method, faithfully (sections 2.1-2.4), as separate building blocks on the slice's ordered 2D polar
curve (points ``value * (sin theta_o, cos theta_o)`` as (x, z), x towards the specular side):

* :func:`split_subcurves` cuts the curve where its acceleration (the turning of its tangent) goes negative ->
  positive -> negative, at the median point of the positive run (2.3), after an optional smoothing;
* :func:`subcurve_axis` gives each sub-curve's axis: vertical through the highest point (2.1) or the first
  principal component of its points (2.4), or whichever fits the sub-curve's symmetry better ("auto");
* :func:`revolve` turns a sub-curve about its axis with Rodrigues' formula, shifting along x so the axis
  passes through the origin and back (2.4);
* :func:`merge_solids` snaps every point's direction to an evenly distributed set of directions, sorts, and
  keeps the highest intensity per direction in O(n log n) (2.2); uncovered directions get 0 (the thesis) or
  are interpolated (its proposed improvement);
* :func:`thesis_hemisphere` chains them: the merged solid for one measured incidence.

The thesis stops at the outgoing hemisphere of the one measured incidence. :func:`reconstruct_revolve`
extends it to a BRDF for every (wi, wo) (see docs/revolve.md): each sub-curve is interpreted as a diffuse,
forward or back-scatter lobe and re-expressed relative to what its axis means (the normal, the mirror
direction of wi, wi itself), as a profile of value against the angle psi from that axis, one profile for each
side of the axis in the plane of incidence and blended by the azimuth around the axis (so the slice itself is
reproduced). A forward lobe's psi is measured as twice the half vector's angle (equal in the measured plane),
and it keeps only its excess over the diffuse lobe, weighted by cos(theta_i) cos(theta_o), which hardly
changes with the incidence for microfacet lobes. Lobes merge by the thesis's rule, the highest luminance
wins. With several incidences, each measured incidence gives such a model and the models are blended linearly
in theta_i.

Multi-channel data: sub-curves, axes and the merge use the luminance-like channel sum; every channel then
follows the same geometry (the same sub-curves, axes and winners).

The package has three rooms: :mod:`.thesis` (the building blocks above), :mod:`.incidence` (a slice as
cleaned curves, one per incidence, with the blind-spot rule shared with :mod:`reconstruction.formats.inputs`, and
:func:`thesis_hemisphere`) and :mod:`.extension` (the full BRDF: :func:`reconstruct_revolve`).

Units: degrees at the public boundary where a name says ``_deg``; radians and unit vectors inside.
"""


from reconstruction.methods.revolve.extension import RevolveReconstruction, reconstruct_revolve, revolve_table
from reconstruction.methods.revolve.incidence import thesis_hemisphere
from reconstruction.methods.revolve.thesis import (
    DEFAULT_MIN_TURN_DEG,
    DEFAULT_SMOOTHING_DEG,
    Axis,
    HemisphereMap,
    direction_grid,
    merge_solids,
    revolve,
    snap_directions,
    split_subcurves,
    subcurve_axis,
)

__all__ = [
    "DEFAULT_SMOOTHING_DEG",
    "DEFAULT_MIN_TURN_DEG",
    "Axis",
    "HemisphereMap",
    "RevolveReconstruction",
    "split_subcurves",
    "subcurve_axis",
    "revolve",
    "direction_grid",
    "snap_directions",
    "merge_solids",
    "thesis_hemisphere",
    "reconstruct_revolve",
    "revolve_table",
]
