"""The shared FLIP pour (tests/data/sims/blender_flip_pour_small.abc) at any resolution, as a PLY sequence.

The FLIP fixture is a Mantaflow liquid at a domain resolution of 40, which is coarse: a studio's
liquid runs at 100 to 300. This script builds the same scene in Blender from the recipe in
tests/data/sims/README.md (a jet from a cylinder into a closed tank, onto a sphere on a pedestal
and round a low wall; Blender's default FLIP settings), bakes it at the resolution asked for and
writes each of the 48 frames' FLIP particles as a binary PLY file (x y z pscale, Alembic's y up,
metres), which `pstream cook` and `pstream bench codec` read as a sequence. At resolution 40 it
gives the fixture's particle counts (116 a frame for the first 13 frames, 7,963 against 7,880 at
frame 48: the solver seeds with randomness) and its size to within a per cent.

Usage (Debian's Blender: it has no Alembic exporter, hence PLY):
  blender -b --factory-startup --python bench/flip_pour_scene.py -- --resolution 80 --out /tmp/pour80
  pstream bench codec /tmp/pour80/frame.0001.ply

Baking takes about 3 s at resolution 40, 40 s at 80 and a few minutes at 120 on two cores; the
cache (in OUT/cache) takes about 40 MB at 80.
"""
import argparse
import os
import struct
import sys

import bpy

FRAMES = 48
DOMAIN = "Domain"


def build(resolution, cache):
    """The scene of tests/data/sims/README.md, Blender's z up, metres, 24 fps."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = 24
    scene.frame_start, scene.frame_end = 1, FRAMES

    def box(name, lo, hi):
        centre = [(a + b) / 2 for a, b in zip(lo, hi)]
        bpy.ops.mesh.primitive_cube_add(location=centre)
        obj = bpy.context.object
        obj.name = name
        obj.scale = [(b - a) / 2 for a, b in zip(lo, hi)]
        bpy.ops.object.transform_apply(scale=True)
        return obj

    def fluid(obj, kind):
        modifier = obj.modifiers.new("Fluid", "FLUID")
        modifier.fluid_type = kind
        return modifier

    domain = fluid(box(DOMAIN, (-1, -0.625, 0), (1, 0.625, 1.5)), "DOMAIN").domain_settings
    domain.domain_type = "LIQUID"  # adds the FLIP particle system
    domain.resolution_max = resolution
    domain.cache_type = "ALL"
    domain.cache_directory = cache
    domain.cache_frame_start, domain.cache_frame_end = 1, FRAMES
    for side in ("front", "back", "right", "left", "top", "bottom"):
        setattr(domain, f"use_collision_border_{side}", True)

    bpy.ops.mesh.primitive_cylinder_add(radius=0.09, depth=0.12, location=(-0.80, 0, 1.15),
                                        rotation=(0, 1.5707963267948966, 0))
    flow = fluid(bpy.context.object, "FLOW").flow_settings
    flow.flow_type, flow.flow_behavior, flow.flow_source = "LIQUID", "INFLOW", "MESH"
    flow.use_initial_velocity = True
    flow.velocity_coord = (2.4, 0, 0.3)

    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.2, location=(0.05, 0, 0.40))
    obstacles = [bpy.context.object]
    bpy.ops.mesh.primitive_cylinder_add(radius=0.07, depth=0.25, location=(0.05, 0, 0.125))
    obstacles.append(bpy.context.object)
    obstacles.append(box("Wall", (0.45, -0.625, 0), (0.55, 0.15, 0.30)))
    for obj in obstacles:
        fluid(obj, "EFFECTOR").effector_settings.effector_type = "COLLISION"
    return bpy.data.objects[DOMAIN]


def write_frames(domain, resolution, out):
    """Each frame's FLIP particles as OUT/frame.NNNN.ply; returns the counts."""
    scene = bpy.context.scene
    # The particles' size as the fixture's widths give it: Mantaflow's surface radius, 0.8747 cells.
    radius = 0.5 * 0.08746856451034546 * 40 / resolution
    counts = []
    for frame in range(1, FRAMES + 1):
        scene.frame_set(frame)
        evaluated = domain.evaluated_get(bpy.context.evaluated_depsgraph_get())
        particles = evaluated.particle_systems[0].particles
        n = len(particles)
        location = [0.0] * (3 * n)
        particles.foreach_get("location", location)
        body = bytearray()
        for i in range(n):
            x, y, z = location[3 * i:3 * i + 3]
            body += struct.pack("<4f", x, z, -y, radius)  # Blender's z up to Alembic's y up
        header = (f"ply\nformat binary_little_endian 1.0\ncomment FLIP pour at resolution {resolution}, frame {frame}\n"
                  f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\nproperty float pscale\n"
                  "end_header\n")
        path = os.path.join(out, f"frame.{frame:04d}.ply")
        with open(path + ".part", "wb") as f:
            f.write(header.encode() + body)
        os.replace(path + ".part", path)
        counts.append(n)
    return counts


def main():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    parser = argparse.ArgumentParser(prog="flip_pour_scene.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolution", type=int, default=40, help="the domain's resolution (the fixture's: 40)")
    parser.add_argument("--out", required=True, help="a folder for the PLY frames and the bake's cache")
    args = parser.parse_args(argv)
    if not 16 <= args.resolution <= 512:
        parser.error(f"--resolution {args.resolution}: expected 16 to 512")
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    domain = build(args.resolution, os.path.join(out, "cache"))
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(out, "scene.blend"))
    with bpy.context.temp_override(object=domain, active_object=domain, scene=bpy.context.scene):
        if bpy.ops.fluid.bake_all() != {"FINISHED"}:
            sys.exit(f"{out}: the bake did not finish")
    counts = write_frames(domain, args.resolution, out)
    print(f"flip_pour_scene: resolution {args.resolution}: {FRAMES} frames in {out}, particles a frame "
          f"{min(counts)} to {max(counts)}, {sum(counts)} in all")
    print("counts " + " ".join(map(str, counts)))


main()
