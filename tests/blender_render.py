"""Render a sphere in Blender (Cycles) as reconstruction.core.render.render_sphere does: run with a Python that has
``bpy`` (tests/external_tools.py makes one), never imported by the suite itself.

    python tests/blender_render.py MATERIAL.py OUT_PREFIX SCENE.json --size 64 --samples 512

The scene is render_sphere's (SCENE.json: the presets' suns and the sky's numbers, taken from
reconstruction.core.render so that this follows the renderer), in Blender's z-up world (ours: x right, y up, z
towards the camera; Blender's: (x, -z, y)): a unit sphere at the origin seen by an orthographic camera whose frame
the sphere fills, the sky-and-ground environment as a world shader of the world elevation (the sky rising
linearly from the horizon to the zenith over the ground, blended by a smoothstep), and each preset's sun (a
delta light). Writes the linear RGB radiance (size, size, 3), row 0 on top, as OUT_PREFIX-NAME.npy per sun.
"""

import argparse
import json
import math
import runpy
import sys

import numpy as np


def to_blender(v):
    from mathutils import Vector  # Blender's own (as bpy: imported here, so pytest's doctest collection can import
    # this file without Blender)

    return Vector((v[0], -v[2], v[1]))


def world_shader(world, sky):
    world.use_nodes = True
    nt = world.node_tree
    nt.nodes.clear()
    tex = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(tex.outputs["Generated"], sep.inputs[0])
    up = sep.outputs["Z"]

    def math_node(op, a, b=None, c=None, clamp=False):
        n = nt.nodes.new("ShaderNodeMath")
        n.operation = op
        n.use_clamp = clamp
        for k, v in enumerate((a, b, c)):
            if v is None:
                continue
            if isinstance(v, float):
                n.inputs[k].default_value = v
            else:
                nt.links.new(v, n.inputs[k])
        return n.outputs[0]

    y01 = math_node("ADD", up, 0.0, clamp=True)
    sky_l = math_node("MULTIPLY_ADD", y01, sky["zenith"] - sky["horizon"], sky["horizon"])
    w = math.sin(math.radians(sky["blend_deg"]))
    ramp = nt.nodes.new("ShaderNodeMapRange")
    ramp.interpolation_type = "SMOOTHSTEP"
    ramp.clamp = True
    nt.links.new(up, ramp.inputs["Value"])
    ramp.inputs["From Min"].default_value = -w
    ramp.inputs["From Max"].default_value = w
    ramp.inputs["To Min"].default_value = 0.0
    ramp.inputs["To Max"].default_value = 1.0
    diff = math_node("SUBTRACT", sky_l, sky["ground"])
    lum = math_node("MULTIPLY_ADD", diff, ramp.outputs["Result"], sky["ground"])
    bg = nt.nodes.new("ShaderNodeBackground")
    comb = nt.nodes.new("ShaderNodeCombineXYZ")
    for k in range(3):
        nt.links.new(lum, comb.inputs[k])
    nt.links.new(comb.outputs[0], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = 1.0
    out = nt.nodes.new("ShaderNodeOutputWorld")
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])


def main(argv):
    import bpy

    ap = argparse.ArgumentParser()
    ap.add_argument("material")
    ap.add_argument("out")
    ap.add_argument("scene", help='{"suns": {"key": [[x, y, z], irradiance], ...}, "sky": {...}}')
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--samples", type=int, default=512)
    a = ap.parse_args(argv)
    with open(a.scene) as fh:
        spec = json.load(fh)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    mat = runpy.run_path(a.material, run_name="gonio_material")["build_material"]()
    bpy.ops.mesh.primitive_uv_sphere_add(segments=192, ring_count=96, radius=1.0)
    sphere = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    sphere.data.materials.append(mat)
    cam_data = bpy.data.cameras.new("cam")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = 2.0
    cam = bpy.data.objects.new("cam", cam_data)
    cam.location = to_blender((0.0, 0.0, 10.0))
    cam.rotation_euler = (math.pi / 2, 0.0, 0.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    sun_data = bpy.data.lights.new("sun", "SUN")
    sun_data.angle = 0.0
    sun = bpy.data.objects.new("sun", sun_data)
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("sky")
    world_shader(world, spec["sky"])
    scene.world = world
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = a.samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.seed = 1
    scene.cycles.filter_width = 0.01
    scene.render.resolution_x = scene.render.resolution_y = a.size
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = True
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    for name, (direction, irradiance) in spec["suns"].items():  # one scene, a render per sun
        sun_data.energy = irradiance
        sun.rotation_euler = to_blender(direction).normalized().to_track_quat("Z", "Y").to_euler()
        exr = f"{a.out}-{name}.exr"
        scene.render.filepath = exr
        bpy.ops.render.render(write_still=True)
        img = bpy.data.images.load(exr)
        px = np.array(img.pixels[:], dtype=np.float64).reshape(a.size, a.size, img.channels)[::-1, :, :3]
        np.save(f"{a.out}-{name}.npy", px)


if __name__ == "__main__":
    main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:])
