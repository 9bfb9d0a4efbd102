"""The picture in docs/blender.md: a clip previewed in the viewport beside the add-on's panel.

    xvfb-run -a -s "-screen 0 1280x1500x24" blender --factory-startup --python-use-system-env \
        --python blender/screenshot.py -- OUT.png CLIP.pstream FRAME
"""
import os
import sys

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import particlestream_blender as addon
addon.register()
bpy.context.preferences.view.show_splash = False
out = sys.argv[sys.argv.index("--") + 1]
clip = sys.argv[sys.argv.index("--") + 2]
frame = int(sys.argv[sys.argv.index("--") + 3])
scene = bpy.context.scene
for o in list(scene.objects):
    bpy.data.objects.remove(o)
scene.frame_start, scene.frame_end = 1, 48
obj, _ = addon.import_clip(bpy.context, clip)
obj.select_set(True)
bpy.context.view_layer.objects.active = obj
scene.frame_set(frame)

def setup():
    for area in bpy.context.screen.areas:
        if area.type == "VIEW_3D":
            space = area.spaces.active
            space.show_region_ui = False
            space.overlay.show_floor = True
            space.overlay.vertex_opacity = 1.0
            space.shading.type = "SOLID"
            with bpy.context.temp_override(area=area, region=[r for r in area.regions if r.type == "WINDOW"][0]):
                bpy.ops.view3d.view_selected()
                bpy.ops.view3d.view_axis(type="FRONT")
                bpy.ops.view3d.view_orbit(angle=0.35, type="ORBITUP")
                bpy.ops.view3d.view_orbit(angle=0.5, type="ORBITLEFT")
                bpy.ops.view3d.view_selected()
    return None


def shoot():
    bpy.ops.screen.screenshot(filepath=out)
    bpy.ops.wm.quit_blender()
    return None

bpy.app.timers.register(setup, first_interval=1.0)
bpy.app.timers.register(shoot, first_interval=4.0)
