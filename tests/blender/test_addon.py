"""The Blender add-on (blender/particlestream_blender), under Debian's Blender headless:

    blender -b --factory-startup --python-use-system-env --python-exit-code 1 \
        --python tests/blender/test_addon.py -- WORK_DIR

1. A particle scene (an emitter with births over frames 1-10, gravity, lifetimes that end inside
   the range, so particles are born and die) is exported with the add-on's operator; every
   exported particle is compared, by id, with Blender's evaluated positions at every frame: the
   same particles alive, each position within the codec's bound.
   Clips are Y-up: Blender's (x, y, z) is the clip's (x, z, -y).
2. The clip is imported back: at every frame the preview mesh's vertices equal the clip's
   decoded positions exactly (turned Z-up), with its sizes as the 'radius' attribute.
3. A mesh whose vertices move (a wave through a displace modifier) exports its vertices.
Exits non-zero on the first failure (--python-exit-code).
"""
import os
import pathlib
import sys

import bpy
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "blender"))
import particlestream as ps  # noqa: E402
import particlestream_blender as addon  # noqa: E402

work = pathlib.Path(sys.argv[sys.argv.index("--") + 1] if "--" in sys.argv else "/tmp")
addon.register()
scene = bpy.context.scene
scene.render.fps = 24
scene.frame_start, scene.frame_end = 1, 30


def check(condition, message):
    if not condition:
        raise AssertionError(message)


def reference(obj, frame):
    """Blender's own answer: alive particles' index -> location, world space."""
    scene.frame_set(frame)
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    out = {}
    for p_index, p in enumerate(evaluated.particle_systems[0].particles):
        if p.alive_state == "ALIVE":
            x, y, z = p.location
            out[p_index] = np.array([x, z, -y], np.float64)  # the clip is Y-up
    return out


# ---- 1. particles out ----------------------------------------------------------------------------
bpy.ops.mesh.primitive_ico_sphere_add(radius=0.5, location=(0.2, 0.1, 1.0))
emitter = bpy.context.active_object
emitter.modifiers.new("sparks", "PARTICLE_SYSTEM")
settings = emitter.particle_systems[0].settings
settings.count = 800
settings.frame_start, settings.frame_end = 1, 10
settings.lifetime, settings.lifetime_random = 14, 0.5
settings.normal_factor = 2.0
settings.particle_size, settings.size_random = 0.03, 0.5
settings.use_rotations = False

clip_path = str(work / "sparks.pstream")
result = bpy.ops.pstream.export(filepath=clip_path, frame_start=1, frame_end=30, ids=True, ages=True)
check(result == {"FINISHED"}, f"export: {result}")
# The frames went through a spool on disk beside the clip: nothing of it is left.
check(sorted(os.listdir(work)) == ["sparks.pstream"], f"the export's folder holds {sorted(os.listdir(work))}")
clip = ps.Clip(clip_path)
check(clip.frame_count == 30, f"{clip.frame_count} frames, expected 30")
check(abs(clip.fps - 24) < 1e-9, f"fps {clip.fps}")
names = [a[0] for a in clip.layout]
check({"position", "scale", "velocity", "id", "age", "life"} <= set(names), f"layout {names}")

all_points = np.concatenate([clip.read_frame(k)["position"] for k in range(30) if clip.count(k)])
diagonal = float(np.linalg.norm(all_points.max(axis=0) - all_points.min(axis=0)))
bound = 1e-4 * diagonal * 1.01  # the default bound: 1e-4 of the source's diagonal (the decoded one, 1 % slack)
worst, compared, births, deaths = 0.0, 0, 0, 0
previous = set()
for k in range(30):
    want = reference(emitter, k + 1)
    records = clip.read_frame(k)
    got = {int(i): p for i, p in zip(records["id"], records["position"])}
    check(set(got) == set(want), f"frame {k + 1}: ids differ: {len(set(got) ^ set(want))} of {len(want)}")
    for i, p in got.items():
        worst = max(worst, float(np.abs(p.astype(np.float64) - want[i]).max()))
    compared += len(got)
    births += len(set(got) - previous)
    deaths += len(previous - set(got))
    previous = set(got)
check(worst <= bound, f"worst position error {worst} > bound {bound}")
check(deaths > 0 and births > 100, f"the scene should have births and deaths: {births} born, {deaths} died")
print(f"export: {compared} particles over 30 frames ({births} born, {deaths} died), worst error {worst:.3g} "
      f"(bound {bound:.3g})")

# Velocities: derived from the positions (the particles have ids), against Blender's own.
scene.frame_set(12)
evaluated = emitter.evaluated_get(bpy.context.evaluated_depsgraph_get())
blender_velocity = {i: np.array([p.velocity[0], p.velocity[2], -p.velocity[1]])
                    for i, p in enumerate(evaluated.particle_systems[0].particles) if p.alive_state == "ALIVE"}
records = clip.read_frame(11)
diff = np.array([records["velocity"][k] - blender_velocity[int(i)] for k, i in enumerate(records["id"])])
speed = np.array([blender_velocity[int(i)] for i in records["id"]])
rms = float(np.sqrt((diff ** 2).sum(axis=1).mean() / (speed ** 2).sum(axis=1).mean()))
check(rms < 0.08, f"derived velocity RMS error {rms:.3%} of Blender's speed")
print(f"velocity: derived within {rms:.2%} RMS of Blender's (units per second)")

# Ages and lifetimes (seconds) against Blender's birth and lifetime (frames), within the codec's
# bound for float attributes: 1e-3 of their range over the clip.
scene.frame_set(12)
evaluated = emitter.evaluated_get(bpy.context.evaluated_depsgraph_get())
alive = {i: p for i, p in enumerate(evaluated.particle_systems[0].particles) if p.alive_state == "ALIVE"}
records = clip.read_frame(11)
errors = []
for name, want in (("age", [(12 - alive[int(i)].birth_time) / 24 for i in records["id"]]),
                   ("life", [alive[int(i)].lifetime / 24 for i in records["id"]])):
    values = np.concatenate([clip.read_frame(k)[name] for k in range(30) if clip.count(k)])
    bound_s = 1e-3 * float(values.max() - values.min()) * 1.01
    error = float(np.abs(records[name] - np.array(want)).max())
    check(len(records) > 100 and error <= bound_s, f"{name}: error {error} s > {bound_s} over {len(records)}")
    errors.append(f"{name} within {error:.3g} s (bound {bound_s:.3g})")
print(f"ages of {len(records)} particles at frame 12: " + ", ".join(errors))

# Sizes: the record's scale is Blender's particle size (a radius).
scene.frame_set(20)
evaluated = emitter.evaluated_get(bpy.context.evaluated_depsgraph_get())
sizes = {i: p.size for i, p in enumerate(evaluated.particle_systems[0].particles) if p.alive_state == "ALIVE"}
records = clip.read_frame(19)
size_error = max(abs(float(s) - sizes[int(i)]) / sizes[int(i)] for i, s in zip(records["id"], records["scale"]))
check(size_error <= 0.0101, f"scale relative error {size_error} > 1 %")
print(f"sizes within {size_error:.3%} of Blender's")

# ---- 2. the clip back in ---------------------------------------------------------------------------
result = bpy.ops.pstream.import_clip(filepath=clip_path)
check(result == {"FINISHED"}, f"import: {result}")
preview = bpy.context.scene.objects["sparks"]
for k in range(30):
    scene.frame_set(k + 1)
    records = clip.read_frame(k)
    mesh = preview.data
    check(len(mesh.vertices) == len(records), f"frame {k + 1}: {len(mesh.vertices)} vertices, clip {len(records)}")
    if len(records) == 0:
        continue
    co = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    p = records["position"]
    z_up = np.stack([p[:, 0], -p[:, 2], p[:, 1]], axis=1)
    check(np.array_equal(co.reshape(-1, 3), z_up), f"frame {k + 1}: vertices differ from the clip (turned Z-up)")
    radius = np.empty(len(mesh.vertices), np.float32)
    mesh.attributes["radius"].data.foreach_get("value", radius)
    check(np.array_equal(radius, records["scale"]), f"frame {k + 1}: radius differs from the clip's scale")
print("import: the preview mesh equals the clip at all 30 frames")
# Drawn as points: the Geometry Nodes modifier turns the vertices into a point cloud whose radii are
# the clip's scales.
scene.frame_set(20)
records = clip.read_frame(19)
depsgraph = bpy.context.evaluated_depsgraph_get()
clouds = [i.object.data for i in depsgraph.object_instances
          if i.object.original == preview and type(i.object.data).__name__ == "PointCloud"]
check(len(clouds) == 1, f"{len(clouds)} point clouds from the preview, expected 1")
cloud = clouds[0]
check(len(cloud.points) == len(records), f"{len(cloud.points)} points, clip {len(records)}")
radius = np.empty(len(cloud.points), np.float32)
cloud.attributes["radius"].data.foreach_get("value", radius)
check(np.array_equal(radius, records["scale"]), "the points' radii differ from the clip's scale")
print(f"import: drawn as {len(cloud.points)} points whose radii are the clip's scales (frame 20)")
# Upright: the emitter sits at z = 1 in Blender and gravity pulls along -z; in the clip that is
# +y up, so the particles' mean height falls over the clip.
heights = [float(clip.read_frame(k)["position"][:, 1].mean()) for k in (2, 12)]
check(heights[1] < heights[0], f"the clip's particles should fall along -y: mean y {heights}")

# ---- 3. a mesh's vertices --------------------------------------------------------------------------
bpy.ops.mesh.primitive_grid_add(x_subdivisions=20, y_subdivisions=20, size=2)
grid = bpy.context.active_object
texture = bpy.data.textures.new("wave", "WOOD")
wave = grid.modifiers.new("wave", "WAVE")
wave.height = 0.3
# Point attributes ride along: a float ('heat') stored on request, a colour named 'color' always.
heat = grid.data.attributes.new("heat", "FLOAT", "POINT")
heat.data.foreach_set("value", np.arange(len(grid.data.vertices), dtype=np.float32) * 0.01)
# Ids from an integer 'id' point attribute (as Geometry Nodes makes), not the vertex index.
vertex_ids = grid.data.attributes.new("id", "INT", "POINT")
vertex_ids.data.foreach_set("value", 5000 - np.arange(len(grid.data.vertices), dtype=np.int32))
tint = grid.data.attributes.new("color", "FLOAT_COLOR", "POINT")
tint.data.foreach_set("color", np.tile(np.array([1.0, 0.5, 0.25, 1.0], np.float32), len(grid.data.vertices)))
mesh_path = str(work / "grid.pstream")
check(bpy.ops.pstream.export(filepath=mesh_path, frame_start=1, frame_end=12, ids=True, attributes=True) == {"FINISHED"},
      "mesh export")
grid_clip = ps.Clip(mesh_path)
stored = grid_clip.read_frame(6)
index = 5000 - stored["id"].astype(np.int64)  # the vertex each particle is
check(sorted(index) == list(range(len(grid.data.vertices))), "the clip's ids are not the 'id' attribute's")
heat_error = float(np.abs(stored["heat"] - index.astype(np.float32) * 0.01).max())
check(heat_error <= 1e-3 * 4.4 * 1.01, f"heat error {heat_error}")
check((stored["color"] == [255, 128, 64, 255]).all(), f"colours {np.unique(stored['color'], axis=0)}")
print(f"mesh attributes: 'heat' within {heat_error:.3g} (bound {1e-3 * 4.4:.3g}), 'color' exact")
scene.frame_set(7)
evaluated = grid.evaluated_get(bpy.context.evaluated_depsgraph_get())
want = np.array([(lambda w: (w.x, w.z, -w.y))(evaluated.matrix_world @ v.co) for v in evaluated.data.vertices],
                np.float64)
got = grid_clip.read_frame(6)
order = np.argsort(5000 - got["id"].astype(np.int64))  # vertex order (ids from the 'id' attribute)
error = float(np.abs(got["position"][order].astype(np.float64) - want).max())
check(grid_clip.count(6) == len(want), f"{grid_clip.count(6)} vertices, expected {len(want)}")
check(error <= 1e-4 * 3.0, f"vertex error {error}")
print(f"mesh vertices: {len(want)} per frame, worst error {error:.3g}")

# The grid's clip imported: coloured, its points carry the clip's colours where Cycles reads them
# ('pstream_color', stored on the points by the coloured group) and take the add-on's material,
# which Cycles renders in those colours.
grid.hide_render = True
check(bpy.ops.pstream.import_clip(filepath=mesh_path) == {"FINISHED"}, "import the grid's clip")
grid_preview = bpy.context.scene.objects["grid"]
check([m.node_group.name for m in grid_preview.modifiers] == ["ParticleStream coloured points"],
      f"the grid's preview modifiers: {[m.name for m in grid_preview.modifiers]}")
check([m.node_group.name for m in preview.modifiers] == ["ParticleStream points"],
      "an uncoloured clip's preview takes the plain points group")
scene.frame_set(7)
depsgraph = bpy.context.evaluated_depsgraph_get()
clouds = [i.object.data for i in depsgraph.object_instances
          if i.object.original == grid_preview and type(i.object.data).__name__ == "PointCloud"]
check(len(clouds) == 1, f"{len(clouds)} point clouds from the grid's preview")
stored_color = np.empty(len(clouds[0].points) * 4, np.float32)
clouds[0].attributes["pstream_color"].data.foreach_get("color", stored_color)
want_color = grid_clip.read_frame(6)["color"].astype(np.float32) / 255.0
check(np.array_equal(stored_color.reshape(-1, 4), want_color), "the points' pstream_color is not the clip's colour")
check([m.name for m in clouds[0].materials] == ["ParticleStream points"], f"materials {list(clouds[0].materials)}")
# Rendered in Cycles (the other objects hidden, a sun above): the grid's points are orange, red
# over green over blue as the clip's (255, 128, 64), not the black the colour came out as before.
for o in scene.objects:
    o.hide_render = o is not grid_preview
sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
sun.data.energy = 3.0
scene.collection.objects.link(sun)
camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
scene.collection.objects.link(camera)
camera.location = (0.0, 0.0, 4.0)  # above the grid, looking down -z
scene.camera = camera
scene.render.engine = "CYCLES"
scene.cycles.samples, scene.cycles.use_denoising = 4, False
scene.view_settings.view_transform = "Standard"  # Filmic would wash the colour out
scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 96, 96, 100
scene.render.filepath = str(work / "grid_cycles.png")
bpy.ops.render.render(write_still=True)
image = bpy.data.images.load(scene.render.filepath)
pixels = np.array(image.pixels[:], np.float32).reshape(-1, 4)[:, :3]
background = np.median(pixels, axis=0)
covered = pixels[np.abs(pixels - background).sum(1) > 0.05]
check(len(covered) > 200, f"{len(covered)} pixels of the grid's points in the Cycles render")
mean = covered.mean(0)
check(mean[0] > 1.15 * mean[1] and mean[1] > 1.15 * mean[2], f"the points' mean colour in Cycles {mean}: not orange")
print(f"import: coloured points in Cycles, {len(covered)} pixels of mean colour {np.round(mean, 3)}")
for o in scene.objects:
    o.hide_render = False

# A mesh whose vertex count changes (a Build modifier revealing its faces) and has no 'id'
# attribute: vertex indices are not ids then, so the clip has none even with "Store ids".
bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=3, location=(4, 0, 0))
sphere = bpy.context.active_object
build = sphere.modifiers.new("build", "BUILD")
build.frame_start, build.frame_duration = 1, 10
counts = []
for f in (2, 6, 11):
    scene.frame_set(f)
    counts.append(len(sphere.evaluated_get(bpy.context.evaluated_depsgraph_get()).data.vertices))
check(counts[0] < counts[1] < counts[2], f"the built sphere's vertex counts {counts} should grow")
built_path = str(work / "built.pstream")
check(bpy.ops.pstream.export(filepath=built_path, frame_start=1, frame_end=12, ids=True) == {"FINISHED"},
      "built sphere export")
built = ps.Clip(built_path)
check("id" not in [a[0] for a in built.layout], f"a growing mesh's clip has ids: {[a[0] for a in built.layout]}")
check(built.count(10) == counts[2], f"{built.count(10)} points at frame 11, Blender {counts[2]}")
print(f"a growing mesh ({counts[0]} -> {counts[2]} vertices): exported without ids")

addon.unregister()
print("blender add-on: all checks passed")
