"""The printed parts of the bench as build123d solids, built from ``hardware/cad/params.toml`` (mm).

Frame (params.toml): the rotation axis is y, the sample's surface the plane z = 0, the plane of incidence y = 0.
Each optic is built along the z axis with z = distance from the rotation axis (so its key planes sit where the
optics need them: the detector aperture at ``optics.detector.distance_mm``); each arm in the plane
``y = arm.plane_offset_mm`` reaching along +z; the assembly (:func:`assembly`) turns arm and optic together by the
arm's angle about y.

Parts: ``arm(p, actuator, role)`` for the XL430/XM430 horn or a NEMA 17 D shaft, for the light or the detector
arm; ``detector_tube`` (field stop, two baffles, the 2.5 mm aperture, the photodiode's pocket);
``collimator_mount`` (output aperture, lens seat, pinhole plane at the lens's focus, LED pocket);
``laser_adapter`` (the alignment laser in the LED's pocket); ``sample_holder`` (the sample's surface pressed from
below against three points in the plane z = 0: on the rotation axis whatever its thickness).
"""

from __future__ import annotations

import math
from typing import Any

from build123d import Align, Box, Cylinder, Part, Pos, Rot

C = (Align.CENTER, Align.CENTER, Align.MIN)   # a cylinder or box standing on z = 0 of its placement
ACTUATORS = ("xl430", "xm430", "nema17")
ROLES = ("light", "detector")


def _ycyl(radius: float, y0: float, y1: float, x: float = 0.0, z: float = 0.0) -> Part:
    """A cylinder along y from ``y0`` to ``y1`` centred on (x, z)."""
    return Pos(x, y0, z) * Rot(-90, 0, 0) * Cylinder(radius, y1 - y0, align=C)


def _zcyl(radius: float, z0: float, z1: float) -> Part:
    """A cylinder along z from ``z0`` to ``z1`` on the z axis."""
    return Pos(0, 0, z0) * Cylinder(radius, z1 - z0, align=C)


def _box(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float) -> Part:
    return Pos(0.5 * (x0 + x1), 0.5 * (y0 + y1), z0) * Box(x1 - x0, y1 - y0, z1 - z0, align=C)


def arm(p: dict[str, Any], actuator: str, role: str) -> Part:
    """An arm: a hub on the rotation axis (the horn's bolt circle, or a D bore with a set screw) and a bar to the
    optic's two M3 holes, in the plane y = plane_offset .. + thickness."""
    a = p["arm"]
    y0, y1 = a["plane_offset_mm"], a["plane_offset_mm"] + a["thickness_mm"]
    holes = a["light_holes_mm"] if role == "light" else a["detector_holes_mm"]
    w = a["width_mm"]
    body = _box(-w / 2, w / 2, y0, y1, 0.0, max(holes) + 10.0) + _ycyl(a["hub_diameter_mm"] / 2, y0, y1)
    for z in holes:
        body -= _ycyl(a["screw_clearance_mm"] / 2, y0 - 1, y1 + 1, z=z)
    if actuator == "nema17":
        n = a["nema17"]
        hub_y1 = y1 + n["hub_length_mm"]
        body += _ycyl(0.35 * a["hub_diameter_mm"], y1, hub_y1)
        bore = _ycyl(n["shaft_mm"] / 2, y0 - 1, hub_y1 + 1)
        flat = n["shaft_flat_mm"] - n["shaft_mm"] / 2        # the D: material back beyond the flat
        body -= bore - _box(flat, n["shaft_mm"], y0 - 2, hub_y1 + 2, -n["shaft_mm"], n["shaft_mm"])
        body -= Pos(0, 0.5 * (y1 + hub_y1), 0) * Rot(0, 90, 0) * Cylinder(n["set_screw_mm"] / 2, 40, align=C)
    else:
        h = a[actuator]
        body -= _ycyl(h["centre_bore_mm"] / 2, y0 - 1, y1 + 1)
        for k in range(h["bolts"]):
            ang = 2 * math.pi * k / h["bolts"] + math.pi / h["bolts"]
            r = h["bolt_circle_mm"] / 2
            body -= _ycyl(h["bolt_clearance_mm"] / 2, y0 - 1, y1 + 1, x=r * math.cos(ang), z=r * math.sin(ang))
    return body


def _bracket(p: dict[str, Any], z0: float, z1: float, holes: list[float], r_body: float) -> Part:
    """The web from an optic's body to its arm's plane, with the arm's two M3 holes."""
    a = p["arm"]
    y_arm = a["plane_offset_mm"]
    web = _box(-5.0, 5.0, 0.0, y_arm, z0, z1)
    for z in holes:
        web -= _ycyl(a["screw_clearance_mm"] / 2, r_body + 1.0, y_arm + 1, z=z)
    return web


def detector_tube(p: dict[str, Any]) -> Part:
    """Field stop, baffles, aperture (on the photodiode) and the photodiode's pocket, along z from the axis."""
    d = p["optics"]["detector"]
    z_ap = d["distance_mm"]
    z_fs = z_ap - d["field_stop_to_aperture_mm"]
    r_out, r_bore, wall = 11.0, 8.0, 1.5
    body = _zcyl(r_out, z_fs - wall, z_ap + 9.0)
    body += _bracket(p, z_fs + 2.0, z_ap + 6.0, p["arm"]["detector_holes_mm"], r_out)
    body -= _zcyl(d["field_stop_mm"] / 2, z_fs - wall - 1, z_fs + 0.01)     # the field stop
    body -= _zcyl(r_bore, z_fs, z_ap - 1.0)                                  # the tube
    body -= _zcyl(d["aperture_mm"] / 2, z_ap - 1.5, z_ap + 0.01)            # the aperture
    body -= _zcyl(5.0, z_ap, z_ap + 9.1)                                     # BPW34 (5.4 x 4.3 mm) and its board
    r_fs, r_ap, length = d["field_stop_mm"] / 2, d["aperture_mm"] / 2, d["field_stop_to_aperture_mm"]
    for frac in (1 / 3, 2 / 3):                                              # baffles, clear of every accepted ray
        z = z_fs + frac * length
        clear = r_fs - (r_fs - r_ap) * frac + 0.6
        body += _zcyl(r_bore + 0.01, z - 0.6, z + 0.6) - _zcyl(clear, z - 1, z + 1)
    return body


def collimator_mount(p: dict[str, Any]) -> Part:
    """Output aperture (the beam), lens seat, the pinhole's plane at the lens's focus and the LED's pocket."""
    c = p["optics"]["collimator"]
    z_out = c["output_aperture_from_axis_mm"]
    z_lens0 = z_out + 2.0                                   # the lens's curved face against this shoulder
    # the pinhole at the back focal length from the lens's flat face: the source at its focus
    z_pin = z_lens0 + c["lens_thickness_mm"] + c["lens_focal_mm"] - c["lens_thickness_mm"] / c["lens_index"]
    r_out = c["lens_diameter_mm"] / 2 + 3.0
    body = _zcyl(r_out, z_out, z_pin + 10.0)
    body += _bracket(p, z_out + 30.0, z_pin, p["arm"]["light_holes_mm"], r_out)
    body -= _zcyl(c["beam_mm"] / 2, z_out - 1, z_lens0 + 0.01)                       # output aperture
    body -= _zcyl(c["lens_diameter_mm"] / 2 + 0.15, z_lens0, z_lens0 + c["lens_thickness_mm"] + 1.0)  # lens seat
    body -= _zcyl(c["lens_diameter_mm"] / 2 - 1.5, z_lens0 + c["lens_thickness_mm"] + 0.99, z_pin - 1.0)
    body -= _zcyl(1.5, z_pin - 1.01, z_pin + 0.01)          # behind the pinhole shim (glued on the plane z_pin)
    body -= _zcyl(10.4, z_pin, z_pin + 10.1)                # the LED's 20 mm star (or the laser adapter)
    return body


def laser_adapter(p: dict[str, Any]) -> Part:
    """A plug for the LED's pocket holding the 12 mm alignment laser on the beam's axis."""
    return _zcyl(10.25, 0.0, 10.0) - _zcyl(6.05, -1.0, 11.0)


def sample_holder(p: dict[str, Any]) -> Part:
    """The sample pressed by a spring from below against three points in the plane z = 0 (its surface on the
    rotation axis whatever its thickness); three radial V grooves underneath sit on three 6 mm balls (a
    Maxwell kinematic mount: the holder comes off and goes back to the same place)."""
    s = p["sample"]
    r_in = s["diameter_mm"] / 2 + 0.15
    r_out = s["holder_outer_mm"] / 2
    depth = s["thickness_max_mm"] + 8.0
    body = _zcyl(r_out, -depth, 0.0) - _zcyl(r_in, -depth + 4.0, 0.01)
    body -= _zcyl(6.0, -depth - 1, -depth + 4.01)           # the spring's plunger
    for k in range(3):
        ang = 90.0 + 120.0 * k
        tab = _box(r_in - 1.5, r_out, -3.0, 3.0, 0.0, 1.5)  # a point: its underside at z = 0, 1.5 mm over the rim
        body += Rot(0, 0, ang) * tab
        groove = Pos(0, 0, -depth) * Rot(0, 0, ang + 60.0) * Pos(0.5 * (r_in + r_out), 0, 0) * Rot(45, 0, 0) \
            * Box(r_out - r_in, 3.0, 3.0)
        body -= groove
    return body


def parts(p: dict[str, Any]) -> dict[str, Part]:
    """Every printed part by its file name."""
    out = {f"arm-{act}-{role}": arm(p, act, role) for act in ACTUATORS for role in ROLES}
    out.update({"detector-tube": detector_tube(p), "collimator-mount": collimator_mount(p),
                "laser-adapter": laser_adapter(p), "sample-holder": sample_holder(p)})
    return out


def assembly(p: dict[str, Any], theta_i_deg: float = 45.0, theta_o_deg: float = 45.0,
             actuator: str = "xm430") -> dict[str, Part]:
    """The bench at (theta_i, theta_o): the light arm and collimator turned to theta_i on the -x side, the
    detector arm and tube to theta_o on the +x side, the sample holder at the centre."""
    light = Rot(0, -theta_i_deg, 0)
    det = Rot(0, theta_o_deg, 0)
    mirror_y = Rot(0, 0, 180)  # the light arm on the other side of the plane of incidence
    return {"sample-holder": sample_holder(p),
            "light-arm": light * mirror_y * arm(p, actuator, "light"),
            "collimator-mount": light * mirror_y * collimator_mount(p),
            "detector-arm": det * arm(p, actuator, "detector"),
            "detector-tube": det * detector_tube(p)}
