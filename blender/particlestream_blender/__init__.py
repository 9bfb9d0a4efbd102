"""ParticleStream for Blender: export particles to a .pstream and preview .pstream clips.

Export takes the active object's particle systems (emitters, and a fluid domain's liquid
particles, which Blender keeps as particle systems), or a mesh or point cloud's vertices, frame by
frame from Blender's evaluated data, and cooks them with the `particlestream` module (no Alembic
involved), turned Y-up as Blender's Alembic exporter turns them. Import brings a clip in as a mesh whose vertices follow the clip on every frame change,
with the clip's sizes and colours as point attributes. docs/blender.md has the details.

Needs the `particlestream` Python module where Blender's Python finds it (`pip install .` from
the ParticleStream repository into that Python, or PYTHONPATH with --python-use-system-env).
"""

bl_info = {
    "name": "ParticleStream",
    "author": "ParticleStream",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "File > Import/Export > ParticleStream (.pstream); Properties > Object > ParticleStream",
    "description": "Export particles to .pstream clips and preview clips as animated point clouds",
    "category": "Import-Export",
}

import os

import bpy
import numpy as np
from bpy.app.handlers import persistent
from bpy.props import BoolProperty, EnumProperty, IntProperty, PointerProperty, StringProperty
from bpy_extras.io_utils import ExportHelper, ImportHelper

_ALIVE = 3  # Particle.alive_state's value for 'ALIVE' (DEAD 1, UNBORN 2, ALIVE 3, DYING 4)
# A mesh's or point cloud's float point attributes: components, and the field foreach_get reads.
_FLOAT_ATTRIBUTES = {"FLOAT": (1, "value"), "FLOAT2": (2, "vector"), "FLOAT_VECTOR": (3, "vector"),
                     "FLOAT_COLOR": (4, "color")}


# Blender is Z-up; .pstream clips, Alembic and the engines they go to are Y-up. Export turns
# Blender's (x, y, z) into (x, z, -y), as Blender's own Alembic exporter does; import turns it back.
def to_y_up(v):
    v = np.asarray(v, np.float32).reshape(-1, 3)
    return np.ascontiguousarray(np.stack([v[:, 0], v[:, 2], -v[:, 1]], axis=1))


def to_z_up(v):
    v = np.asarray(v, np.float32).reshape(-1, 3)
    return np.ascontiguousarray(np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1))
_clips = {}  # path -> particlestream.Clip, opened once per session


def _module():
    try:
        import particlestream
    except ImportError as e:
        raise RuntimeError(
            "the particlestream Python module is not installed for Blender's Python: run `pip install .` from the "
            f"ParticleStream repository with the Python Blender uses ({e})") from e
    return particlestream


# ---- export -------------------------------------------------------------------------------------

def particle_frame(obj, depsgraph, ages=None):
    """The object's particles in the evaluated scene as arrays (world space), or None when it has
    neither particle systems nor vertices. Particle systems: the alive particles of each, ids from
    their index (stable in Blender) offset per system, sizes as widths (2 x size: Blender's size is
    a radius), velocities, and with `ages` = (scene frame, fps) their 'age' and 'life' in seconds
    (since birth, and the lifetime). Vertices: positions through the object's matrix, ids from the
    'id' point attribute, or the vertex index when the count never changes (the caller checks:
    'ids_are_indices'), the 'velocity', 'radius' and 'color' attributes, and the float ones in
    'attributes'."""
    evaluated = obj.evaluated_get(depsgraph)
    if len(evaluated.particle_systems):
        parts, offset = [], 0
        for system in evaluated.particle_systems:
            particles = system.particles
            n = len(particles)
            if n == 0:
                continue
            state = np.empty(n, np.int32)
            particles.foreach_get("alive_state", state)
            location = np.empty(n * 3, np.float32)
            particles.foreach_get("location", location)
            velocity = np.empty(n * 3, np.float32)
            particles.foreach_get("velocity", velocity)
            size = np.empty(n, np.float32)
            particles.foreach_get("size", size)
            alive = state == _ALIVE
            ids = np.nonzero(alive)[0].astype(np.uint64) + np.uint64(offset)
            age = life = None
            if ages is not None:  # Blender keeps birth and lifetime in frames
                birth = np.empty(n, np.float32)
                particles.foreach_get("birth_time", birth)
                lifetime = np.empty(n, np.float32)
                particles.foreach_get("lifetime", lifetime)
                age = (np.float32(ages[0]) - birth[alive]) / np.float32(ages[1])
                life = lifetime[alive] / np.float32(ages[1])
            parts.append((location.reshape(-1, 3)[alive], velocity.reshape(-1, 3)[alive], 2.0 * size[alive], ids,
                          age, life))
            offset += n
        if not parts:
            return {"position": np.zeros((0, 3), np.float32)}
        frame = {
            "position": np.concatenate([p[0] for p in parts]),
            "velocity": np.concatenate([p[1] for p in parts]),
            "width": np.concatenate([p[2] for p in parts]).astype(np.float32),
            "id": np.concatenate([p[3] for p in parts]),
        }
        if ages is not None:
            frame["attributes"] = {"age": np.concatenate([p[4] for p in parts]),
                                   "life": np.concatenate([p[5] for p in parts])}
        return frame
    data = getattr(evaluated, "data", None)
    points = getattr(data, "vertices", None) if isinstance(data, bpy.types.Mesh) else getattr(data, "points", None)
    if points is None:
        return None
    n = len(points)
    local = np.empty(n * 3, np.float32)
    points.foreach_get("co", local)
    matrix = np.array(evaluated.matrix_world, dtype=np.float64)
    position = (local.reshape(-1, 3) @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)
    frame = {"position": position}
    attribute = data.attributes.get("velocity") if hasattr(data, "attributes") else None
    if attribute is not None and attribute.data_type == "FLOAT_VECTOR" and attribute.domain == "POINT":
        velocity = np.empty(n * 3, np.float32)
        attribute.data.foreach_get("vector", velocity)
        frame["velocity"] = (velocity.reshape(-1, 3) @ matrix[:3, :3].T).astype(np.float32)
    radius = data.attributes.get("radius") if hasattr(data, "attributes") else None
    if radius is not None and radius.data_type == "FLOAT" and radius.domain == "POINT":
        r = np.empty(n, np.float32)
        radius.data.foreach_get("value", r)
        frame["width"] = 2.0 * r
    # Ids: an integer point attribute named 'id' (Geometry Nodes makes one, stable across frames),
    # else the vertex index, which the caller keeps only while the count holds.
    id_attribute = data.attributes.get("id") if hasattr(data, "attributes") else None
    if id_attribute is not None and id_attribute.data_type == "INT" and id_attribute.domain == "POINT":
        ids = np.empty(n, np.int32)
        id_attribute.data.foreach_get("value", ids)
        frame["id"] = ids.view(np.uint32).astype(np.uint64)  # negative ids (hashes) stay distinct
    else:
        frame["id"] = np.arange(n, dtype=np.uint64)
        frame["ids_are_indices"] = True
    # The other point attributes: a colour named 'color' (linear RGBA), and every float one (as it is
    # stored: vectors stay in the object's space) for the cook's `attributes`.
    extra = {}
    for a in getattr(data, "attributes", []):
        if a.domain != "POINT" or a.name.startswith(".") or a.name in ("position", "radius", "velocity", "id"):
            continue
        if a.name == "color" and a.data_type in ("FLOAT_COLOR", "BYTE_COLOR"):
            color = np.empty(n * 4, np.float32)
            a.data.foreach_get("color", color)
            frame["color"] = color.reshape(-1, 4)
        elif a.data_type in _FLOAT_ATTRIBUTES:
            k, field = _FLOAT_ATTRIBUTES[a.data_type]
            values = np.empty(n * k, np.float32)
            a.data.foreach_get(field, values)
            extra[a.name] = values.reshape(n, k) if k > 1 else values
    if extra:
        frame["attributes"] = extra
    return frame


def export_clip(context, obj, filepath, frame_start, frame_end, codec="particle", error="1e-4", ids=False, report=None,
                ages=False, attributes=False):
    """Cooks `obj`'s particles over [frame_start, frame_end] into `filepath`; returns the cook's
    report. `report(done, total, what)` follows the progress. `ages`: keep particle systems' age
    and life (seconds) as the clip's 'age' and 'life' attributes. `attributes`: keep a mesh's or
    point cloud's float point attributes (those of its first frame with points)."""
    ps = _module()
    scene = context.scene
    fps = scene.render.fps / scene.render.fps_base
    wm = context.window_manager
    total = frame_end - frame_start + 1
    counts, extra, indices = set(), None, False
    # Vertices (no particle systems): their indices are ids only while the count holds.
    from_particles = len(obj.particle_systems) > 0
    current = scene.frame_current
    name = f"Blender {os.path.basename(bpy.data.filepath) or 'untitled'}: {obj.name}"
    # Each frame goes to disk as it is read (an unnamed temporary beside the clip), so a long,
    # large simulation needs disk for its frames, not memory.
    spool = ps.FrameSpool(name, os.path.dirname(os.path.abspath(filepath)))
    wm.progress_begin(0, 2 * total)
    try:
        for k, f in enumerate(range(frame_start, frame_end + 1)):
            scene.frame_set(f)
            frame = particle_frame(obj, context.evaluated_depsgraph_get(), (f, fps) if ages and from_particles else None)
            if frame is None:
                raise RuntimeError(f"{obj.name} has no particle systems, mesh vertices or points to export")
            frame["time"] = f / fps
            frame["position"] = to_y_up(frame["position"])
            if "velocity" in frame:
                frame["velocity"] = to_y_up(frame["velocity"])
            counts.add(len(frame["position"]))
            indices = frame.pop("ids_are_indices", False) or indices
            if not from_particles and not attributes:
                frame.pop("attributes", None)  # not stored: not spooled either
            if extra is None and len(frame["position"]) and not from_particles:
                extra = list(frame.get("attributes", {}))  # stored: those of the first frame with points
            spool.add_frame(frame)
            wm.progress_update(k + 1)
            if report:
                report(k + 1, total, "frames read")
        no_ids = indices and len(counts) > 1  # vertex indices, and the count changes: not ids
        if no_ids:
            spool.drop_ids()

        def progress(done, count):  # the cook's passes over the frames: the second half of the bar
            wm.progress_update(total + total * done / max(count, 1))
            if report:
                report(done, count, "frames cooked")

        stored = (["id"] if ids and not no_ids else []) + (["age", "life"] if ages and from_particles else []) + (
            extra or [])
        result = ps.cook_particles(spool, filepath, fps=fps, name=name, object=obj.name, codec=codec, error=error,
                                   attributes=stored, progress=progress)
        if ids and no_ids:
            result["note"] = (f"{obj.name}'s vertex count changes and it has no integer 'id' point attribute, so its "
                              "vertex indices are not ids: the clip stores none")
        return result
    finally:
        spool.close()
        wm.progress_end()
        scene.frame_set(current)


_CODECS = [
    ("particle", "Particle", "Error-bounded, predicted over time: about 1-3 bytes a particle a frame"),
    ("particle-lossless", "Lossless", "Bit-exact positions, the source order kept"),
    ("zstd", "zstd", "The records as they are, chunk-compressed")]
_ERROR_HELP = "Position bound: a fraction of the clip's bounds diagonal (1e-4), or abs:0.001 in scene units"
_IDS_HELP = "Keep each particle's id in the clip (frames are ordered by id either way)"
_ATTRIBUTES_HELP = ("Keep a mesh's or point cloud's float point attributes (temperature, ...) in the clip, "
                    "for colour ramps: pstream render --color-by attribute --ramp-attribute NAME")
_AGES_HELP = ("Keep each particle's age and lifetime in seconds as the clip's 'age' and 'life' attributes "
              "(colour ramps: pstream render --color-by attribute --ramp-attribute age)")


class PSTREAM_OT_export(bpy.types.Operator, ExportHelper):
    """Cook the active object's particles (particle systems, a fluid's liquid particles, or its
    vertices) over the frame range into a .pstream"""
    bl_idname = "pstream.export"
    bl_label = "Export ParticleStream"
    filename_ext = ".pstream"
    filter_glob: StringProperty(default="*.pstream", options={"HIDDEN"})
    frame_start: IntProperty(name="Start", description="First frame (0: the scene's)", default=0)
    frame_end: IntProperty(name="End", description="Last frame (0: the scene's)", default=0)
    codec: EnumProperty(name="Codec", default="particle", items=_CODECS)
    error: StringProperty(name="Error", default="1e-4", description=_ERROR_HELP)
    ids: BoolProperty(name="Store ids", default=False, description=_IDS_HELP)
    ages: BoolProperty(name="Store ages", default=False, description=_AGES_HELP)
    attributes: BoolProperty(name="Store attributes", default=False, description=_ATTRIBUTES_HELP)

    def execute(self, context):
        obj = context.active_object
        if obj is None:
            self.report({"ERROR"}, "select the object whose particles to export")
            return {"CANCELLED"}
        scene = context.scene
        start = self.frame_start or scene.frame_start
        end = self.frame_end or scene.frame_end
        try:
            r = export_clip(context, obj, self.filepath, start, end, self.codec, self.error, self.ids, ages=self.ages,
                            attributes=self.attributes)
        except Exception as e:  # the module's messages name the frame and what is wrong
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        if "note" in r:
            self.report({"WARNING"}, r["note"])
        self.report({"INFO"}, f"{self.filepath}: {r['frames']} frames, {r['particles']} particles, "
                              f"{r['file_bytes']} bytes")
        return {"FINISHED"}


# ---- import (preview) -----------------------------------------------------------------------------

def _clip(path):
    clip = _clips.get(path)
    if clip is None:
        clip = _clips[path] = _module().Clip(path)
    return clip


def clip_frame_at(clip, scene_time):
    """The clip's frame nearest the scene's time (clamped to the clip)."""
    n = clip.frame_count
    if n == 0:
        return -1
    first, step = clip.time(0), 1.0 / clip.fps
    return int(min(max(round((scene_time - first) / step), 0), n - 1))


def update_preview(obj, scene):
    """Sets the preview mesh's vertices to the clip's frame at the scene's time (turned Z-up), with
    'radius' (the record's scale) and 'color' point attributes."""
    clip = _clip(bpy.path.abspath(obj["pstream_path"]))
    fps = scene.render.fps / scene.render.fps_base
    frame = clip_frame_at(clip, scene.frame_current / fps)
    records = clip.read_frame(frame) if frame >= 0 else None
    mesh = obj.data
    mesh.clear_geometry()
    n = 0 if records is None else len(records)
    if n == 0:
        return
    mesh.vertices.add(n)
    mesh.vertices.foreach_set("co", to_z_up(records["position"]).ravel())
    names = records.dtype.names
    if "scale" in names:
        radius = mesh.attributes.get("radius") or mesh.attributes.new("radius", "FLOAT", "POINT")
        radius.data.foreach_set("value", np.ascontiguousarray(records["scale"], np.float32))
    if "color" in names:
        color = mesh.attributes.get("color") or mesh.attributes.new("color", "FLOAT_COLOR", "POINT")
        color.data.foreach_set("color", (records["color"].astype(np.float32) / 255.0).ravel())
    mesh.update()


@persistent
def _on_frame_change(scene, depsgraph=None):
    for obj in scene.objects:
        if "pstream_path" in obj and obj.type == "MESH":
            try:
                update_preview(obj, scene)
            except Exception as e:
                print(f"ParticleStream: {obj.name}: {e}")


_POINTS_GROUP = "ParticleStream points"
_COLOURED_POINTS_GROUP = "ParticleStream coloured points"
_POINTS_MATERIAL = "ParticleStream points"
# The points' colour as Cycles reads it. Cycles in Blender 3.4 renders the attributes Mesh to Points
# carries over from the mesh as black; an attribute the group stores on the points itself reaches
# the material.
_POINT_COLOR = "pstream_color"


def _points_material():
    """The material of coloured previews: each point's base colour is its clip colour."""
    material = bpy.data.materials.get(_POINTS_MATERIAL)
    if material is not None:
        return material
    material = bpy.data.materials.new(_POINTS_MATERIAL)
    material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    shader = next(n for n in nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    color = nodes.new("ShaderNodeAttribute")
    color.attribute_type = "GEOMETRY"
    color.attribute_name = _POINT_COLOR
    color.location = (shader.location.x - 250, shader.location.y)
    links.new(color.outputs["Color"], shader.inputs["Base Color"])
    return material


def _points_group(coloured):
    """Geometry Nodes that draw the preview's vertices as points: Mesh to Points, each point's radius
    the 'radius' attribute (the clip's scale); `coloured`: the 'color' attribute stored on the points
    and the points given the preview material, which shows it. One group of each kind, shared by
    the previews."""
    name = _COLOURED_POINTS_GROUP if coloured else _POINTS_GROUP
    tree = bpy.data.node_groups.get(name)
    if tree is not None:
        return tree
    tree = bpy.data.node_groups.new(name, "GeometryNodeTree")
    if hasattr(tree, "interface"):  # Blender 4
        tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
        tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    else:
        tree.inputs.new("NodeSocketGeometry", "Geometry")
        tree.outputs.new("NodeSocketGeometry", "Geometry")
    nodes, links = tree.nodes, tree.links

    def named(data_type, attribute, socket_type):
        node = nodes.new("GeometryNodeInputNamedAttribute")
        node.data_type = data_type
        node.inputs["Name"].default_value = attribute
        return node, next(o for o in node.outputs if o.type == socket_type and o.enabled)

    given, result = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    radius, radius_value = named("FLOAT", "radius", "VALUE")
    points = nodes.new("GeometryNodeMeshToPoints")
    links.new(given.outputs[0], points.inputs["Mesh"])
    links.new(radius_value, points.inputs["Radius"])
    chain = [given, radius, points]
    geometry = points.outputs["Points"]
    if coloured:
        color, color_value = named("FLOAT_COLOR", "color", "RGBA")
        store = nodes.new("GeometryNodeStoreNamedAttribute")
        store.data_type, store.domain = "FLOAT_COLOR", "POINT"
        store.inputs["Name"].default_value = _POINT_COLOR
        links.new(geometry, store.inputs["Geometry"])
        links.new(color_value, next(i for i in store.inputs if i.type == "RGBA" and i.enabled))
        material = nodes.new("GeometryNodeSetMaterial")
        material.inputs["Material"].default_value = _points_material()
        links.new(store.outputs["Geometry"], material.inputs["Geometry"])
        geometry = material.outputs["Geometry"]
        chain += [color, store, material]
    links.new(geometry, result.inputs[0])
    for k, node in enumerate(chain + [result]):
        node.location = (200 * k, 0)
    return tree


def import_clip(context, filepath):
    """A mesh object previewing the clip at `filepath`, its vertices drawn as points of the clip's
    sizes by a Geometry Nodes modifier; returns it and the clip."""
    clip = _clip(filepath)
    name = os.path.splitext(os.path.basename(filepath))[0]
    mesh = bpy.data.meshes.new(name)
    obj = bpy.data.objects.new(name, mesh)
    obj["pstream_path"] = filepath
    context.collection.objects.link(obj)
    update_preview(obj, context.scene)
    names = [a[0] for a in clip.layout]
    if "scale" in names:
        group = _points_group("color" in names)
        modifier = obj.modifiers.new(group.name, "NODES")
        modifier.node_group = group
    return obj, clip


class PSTREAM_OT_import(bpy.types.Operator, ImportHelper):
    """Preview a .pstream as a point cloud that follows the clip on every frame"""
    bl_idname = "pstream.import_clip"
    bl_label = "Import ParticleStream"
    filename_ext = ".pstream"
    filter_glob: StringProperty(default="*.pstream", options={"HIDDEN"})

    def execute(self, context):
        try:
            obj, clip = import_clip(context, self.filepath)
        except Exception as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report({"INFO"}, f"{obj.name}: {clip.frame_count} frames at {clip.fps:g} fps")
        return {"FINISHED"}


# ---- UI -------------------------------------------------------------------------------------------

class PSTREAM_settings(bpy.types.PropertyGroup):
    """The panel's export settings, kept with the scene."""
    filepath: StringProperty(name="File", subtype="FILE_PATH", default="//particles.pstream",
                             description="The .pstream to write (// is the .blend file's folder)")
    codec: EnumProperty(name="Codec", default="particle", items=_CODECS)
    error: StringProperty(name="Error", default="1e-4", description=_ERROR_HELP)
    ids: BoolProperty(name="Store ids", default=False, description=_IDS_HELP)
    ages: BoolProperty(name="Store ages", default=False, description=_AGES_HELP)
    attributes: BoolProperty(name="Store attributes", default=False, description=_ATTRIBUTES_HELP)


class PSTREAM_PT_panel(bpy.types.Panel):
    """Object properties: export the active object's particles with the codec's options, or
    preview a clip."""
    bl_label = "ParticleStream"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"
    bl_order = 0  # first among the object's panels

    def draw(self, context):
        layout = self.layout
        settings = context.scene.pstream
        obj = context.active_object
        if obj is not None and "pstream_path" in obj:
            layout.label(text=f"Previewing {os.path.basename(obj['pstream_path'])}", icon="PARTICLES")
        col = layout.column(align=True)
        col.prop(settings, "filepath")
        col.prop(settings, "codec")
        if settings.codec == "particle":
            col.prop(settings, "error")
        col.prop(settings, "ids")
        col.prop(settings, "ages")
        col.prop(settings, "attributes")
        row = layout.row(align=True)
        row.prop(context.scene, "frame_start", text="Start")
        row.prop(context.scene, "frame_end", text="End")
        op = layout.operator(PSTREAM_OT_export.bl_idname, text="Export", icon="EXPORT")
        op.filepath = bpy.path.abspath(settings.filepath)
        op.codec, op.error, op.ids = settings.codec, settings.error, settings.ids
        op.ages, op.attributes = settings.ages, settings.attributes
        layout.operator(PSTREAM_OT_import.bl_idname, text="Import a clip", icon="IMPORT")


def _menu_export(self, context):
    self.layout.operator(PSTREAM_OT_export.bl_idname, text="ParticleStream (.pstream)")


def _menu_import(self, context):
    self.layout.operator(PSTREAM_OT_import.bl_idname, text="ParticleStream (.pstream)")


_classes = (PSTREAM_settings, PSTREAM_OT_export, PSTREAM_OT_import, PSTREAM_PT_panel)


def register():
    for c in _classes:
        bpy.utils.register_class(c)
    bpy.types.Scene.pstream = PointerProperty(type=PSTREAM_settings)
    bpy.types.TOPBAR_MT_file_export.append(_menu_export)
    bpy.types.TOPBAR_MT_file_import.append(_menu_import)
    if _on_frame_change not in bpy.app.handlers.frame_change_post:
        bpy.app.handlers.frame_change_post.append(_on_frame_change)


def unregister():
    if _on_frame_change in bpy.app.handlers.frame_change_post:
        bpy.app.handlers.frame_change_post.remove(_on_frame_change)
    bpy.types.TOPBAR_MT_file_import.remove(_menu_import)
    bpy.types.TOPBAR_MT_file_export.remove(_menu_export)
    del bpy.types.Scene.pstream
    for c in reversed(_classes):
        bpy.utils.unregister_class(c)
    _clips.clear()
