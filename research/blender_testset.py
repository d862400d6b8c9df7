"""An independent test set for stackgen: piles made and rendered another way, inside Blender.

Run by research/make-blender-testset (blender --background --factory-startup --python this file --
ARGS). Nothing of stackgen's is used but the part's mesh files: Blender's own rigid-body world
(its Bullet) drops the connectors into a box bin (walls that only the physics sees continue 300
mm above the rim while the pile forms; a pile resting above the real rim is refused), Cycles
path-traces the pile (physically based
materials, an HDR environment from Debian's blender-data, an optional ceiling panel, Filmic view
transform), and the labels come from Cycles' object-index pass rendered with one sample at each
pixel's centre (a box filter 0.01 px wide), each part also alone for its unoccluded area. It
writes a COCO dataset like stackgen-coco's: DIR/annotations.json (uncompressed RLE masks;
iscrowd 1 for parts less than 30 % visible, as stackgen's ignore regions) and DIR/images/*.png,
plus DIR/README.txt saying how it was made.
"""
import argparse
import colorsys
import glob
import json
import math
import os
import random
import shutil
import sys
import time

import bpy
import mathutils
import numpy as np

MM = 0.001  # Blender works in metres

# the pass index of the surfaces, and what the region map (regions/*.png; stackgen.metrics'
# REGION_*) says they are: 1 the bin floor, 2 its walls and rim, 0 the table and all else
FLOOR_INDEX, WALLS_INDEX, TABLE_INDEX = 201, 202, 203
REGION_OF_INDEX = {FLOOR_INDEX: 1, WALLS_INDEX: 2}

# What a scene is drawn from. "narrow", the first sets' recipe: the default bin's size, a tote of
# five dark colours, a grey table, an HDR environment and now and then a ceiling panel, the camera
# 450 +- 30 mm above, rolled +-10 degrees, 12 parts, no sensor. The others draw from what real
# picking cells show, wider than stackgen's default: totes of every colour and bare steel, of
# several sizes and wall thicknesses, dusty or clean; wood, steel, painted or rubber tables; light
# of several kinds and colour temperatures over a dimmer environment; a camera anywhere from 410
# to 530 mm, turned any way, tilted up to 10 degrees, with an exposure, a tone curve (filmic or a
# plain clipping one), a white balance, defocus, shot and read noise of its own; 6 to 16 parts.
# "shop" is lit by LED strips, ceiling panels and ring lights; "daylight" by the sun, a window,
# a ring light and strips, with warmer light, wood tables and a noisier camera.
RECIPES = {
    "narrow": None,
    "shop": dict(
        totes=("blue", "grey", "black", "yellow", "green", "red", "white", "steel"),
        tables=("steel", "painted", "rubber", "wood"),
        lights=("strips", "panel", "ring"), kelvin=(4000, 6500), environment=(0.05, 0.5),
        exposure_ev=(-1.5, 1.0), shot_noise=(0.0, 0.003), read_noise=(0.0, 0.008)),
    "daylight": dict(
        totes=("white", "yellow", "blue", "green", "red", "grey", "black", "steel"),
        tables=("wood", "painted", "steel"),
        lights=("sun", "window", "ring", "strips"), kelvin=(3000, 6000), environment=(0.1, 1.0),
        exposure_ev=(-1.5, 1.0), shot_noise=(0.0, 0.006), read_noise=(0.002, 0.015)),
}

# tote colours: hue (degrees), saturation and value ranges of the display colour
TOTE_COLOURS = {
    "blue": ((205, 225), (0.55, 0.85), (0.25, 0.6)),
    "grey": ((0, 360), (0.0, 0.06), (0.25, 0.6)),
    "black": ((0, 360), (0.0, 0.1), (0.04, 0.12)),
    "yellow": ((42, 55), (0.75, 0.95), (0.7, 0.95)),
    "green": ((100, 145), (0.45, 0.8), (0.25, 0.55)),
    "red": ((352, 368), (0.65, 0.9), (0.45, 0.75)),
    "white": ((0, 360), (0.0, 0.05), (0.78, 0.93)),
}


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    parser = argparse.ArgumentParser(prog="make-blender-testset", allow_abbrev=False)
    parser.add_argument("--out", required=True)
    parser.add_argument("--count", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--parts", type=int, default=12)
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--mesh", required=True)
    parser.add_argument("--collision-mesh", required=True)
    parser.add_argument("--environments", default="/usr/share/blender/datafiles/studiolights/world")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--fx", type=float, default=800.0)
    parser.add_argument("--recipe", choices=sorted(RECIPES), default="narrow")
    args = parser.parse_args(argv)
    if args.count < 1 or args.parts < 1 or args.samples < 1:
        parser.error("--count, --parts and --samples want whole numbers >= 1")
    return args


def import_obj(path):
    """The objects of an OBJ file (millimetres, z up), scaled to metres, transforms applied."""
    before = set(bpy.data.objects)
    bpy.ops.wm.obj_import(filepath=path, forward_axis="Y", up_axis="Z")
    objects = [o for o in bpy.data.objects if o not in before]
    for o in objects:
        o.data.transform(mathutils.Matrix.Scale(MM, 4))
        o.matrix_world = mathutils.Matrix.Identity(4)
    return objects


def box(name, size, location, passive=True):
    bpy.ops.mesh.primitive_cube_add(size=1, location=location)
    o = bpy.context.active_object
    o.name = name
    o.scale = size
    bpy.ops.object.transform_apply(location=False, rotation=False, scale=True)
    if passive:
        bpy.ops.rigidbody.object_add(type="PASSIVE")
        o.rigid_body.collision_shape = "BOX"
        o.rigid_body.friction = 0.6
        o.rigid_body.restitution = 0.1
        o.rigid_body.use_margin = True
        o.rigid_body.collision_margin = 0.0005
    return o


def principled(name, color, metallic, roughness, noise_roughness=0.0):
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    nodes = material.node_tree.nodes
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Roughness"].default_value = roughness
    if noise_roughness > 0:
        # a cast surface: roughness varying over millimetres
        noise = nodes.new("ShaderNodeTexNoise")
        noise.inputs["Scale"].default_value = 400.0
        ramp = nodes.new("ShaderNodeMapRange")
        ramp.inputs["To Min"].default_value = max(0.0, roughness - noise_roughness)
        ramp.inputs["To Max"].default_value = min(1.0, roughness + noise_roughness)
        material.node_tree.links.new(noise.outputs["Fac"], ramp.inputs["Value"])
        material.node_tree.links.new(ramp.outputs["Result"], bsdf.inputs["Roughness"])
    return material


def linear(rgb):
    """A display (sRGB) colour as the linear one Blender's materials take."""
    return tuple(c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in rgb)


def drawn_colour(rng, hue, saturation, value):
    """A display colour of hue (degrees), saturation and value drawn from their ranges."""
    return colorsys.hsv_to_rgb((rng.uniform(*hue) % 360) / 360, rng.uniform(*saturation),
                               rng.uniform(*value))


def noise_into(material, rng, scale, low, high, target, stretch=(1, 1, 1)):
    """Drives `target` (a socket of the material's Principled BSDF) with noise between low and
    high: Object coordinates (metres) stretched per axis, a new offset per draw."""
    tree = material.node_tree
    coordinates = tree.nodes.new("ShaderNodeTexCoord")
    mapping = tree.nodes.new("ShaderNodeMapping")
    mapping.inputs["Location"].default_value = (rng.uniform(0, 100), rng.uniform(0, 100), 0)
    mapping.inputs["Scale"].default_value = stretch
    noise = tree.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = scale
    noise.inputs["Detail"].default_value = 4.0
    ramp = tree.nodes.new("ShaderNodeMapRange")
    ramp.inputs["From Min"].default_value = 0.3
    ramp.inputs["From Max"].default_value = 0.7
    ramp.inputs["To Min"].default_value = low
    ramp.inputs["To Max"].default_value = high
    tree.links.new(coordinates.outputs["Object"], mapping.inputs["Vector"])
    tree.links.new(mapping.outputs["Vector"], noise.inputs["Vector"])
    tree.links.new(noise.outputs["Fac"], ramp.inputs["Value"])
    tree.links.new(ramp.outputs["Result"], target)


def dusty(material, rng, colour):
    """Dust and grime: the base colour mixed with a dust grey in patches of a few centimetres."""
    tree = material.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    mix = tree.nodes.new("ShaderNodeMixRGB")
    mix.inputs["Color1"].default_value = (*linear(colour), 1.0)
    dust = rng.uniform(0.35, 0.6)
    mix.inputs["Color2"].default_value = (*linear((dust, dust * 0.96, dust * 0.9)), 1.0)
    noise_into(material, rng, rng.uniform(15, 60), 0.0, rng.uniform(0.3, 0.8), mix.inputs["Fac"])
    tree.links.new(mix.outputs["Color"], bsdf.inputs["Base Color"])


def tote_material(rng, kind):
    """A tote of a named kind: plastic of a drawn colour (dusty half the time) or bare steel,
    brushed; returns the material and a note."""
    if kind == "steel":
        grey = rng.uniform(0.55, 0.8)
        roughness = rng.uniform(0.15, 0.45)
        material = principled("tote", linear((grey, grey, grey * 1.02)), 1.0, roughness)
        noise_into(material, rng, 40, max(0.05, roughness - 0.15), min(1.0, roughness + 0.15),
                   material.node_tree.nodes["Principled BSDF"].inputs["Roughness"],
                   stretch=(1, 80, 1))
        return material, f"steel tote (grey {grey:.2f}, roughness {roughness:.2f})"
    colour = drawn_colour(rng, *TOTE_COLOURS[kind])
    roughness = rng.uniform(0.3, 0.8)
    material = principled("tote", linear(colour), 0.0, roughness)
    dirt = rng.random() < 0.5
    if dirt:
        dusty(material, rng, colour)
    return material, (f"{kind} tote ({', '.join(f'{c:.2f}' for c in colour)}, roughness "
                      f"{roughness:.2f}{', dusty' if dirt else ''})")


def table_material(rng, kind):
    """A table top of a named kind: wood (grain from a distorted wave), brushed steel, painted
    (a muted colour, scuffed now and then) or rubber; returns the material and a note."""
    if kind == "wood":
        material = principled("table", (0.3, 0.2, 0.1), 0.0, rng.uniform(0.35, 0.75))
        tree = material.node_tree
        # growth rings about 1-3 cm apart (Object coordinates, metres), turned and distorted
        coordinates = tree.nodes.new("ShaderNodeTexCoord")
        mapping = tree.nodes.new("ShaderNodeMapping")
        mapping.inputs["Rotation"].default_value = (0, 0, rng.uniform(0, math.pi))
        wave = tree.nodes.new("ShaderNodeTexWave")
        wave.inputs["Scale"].default_value = rng.uniform(20, 50)
        wave.inputs["Distortion"].default_value = rng.uniform(4, 12)
        wave.inputs["Detail"].default_value = 3.0
        tree.links.new(coordinates.outputs["Object"], mapping.inputs["Vector"])
        tree.links.new(mapping.outputs["Vector"], wave.inputs["Vector"])
        ramp = tree.nodes.new("ShaderNodeValToRGB")
        light = drawn_colour(rng, (25, 40), (0.35, 0.6), (0.45, 0.85))
        dark = [c * rng.uniform(0.45, 0.75) for c in light]
        ramp.color_ramp.elements[0].color = (*linear(dark), 1.0)
        ramp.color_ramp.elements[1].color = (*linear(light), 1.0)
        tree.links.new(wave.outputs["Fac"], ramp.inputs["Fac"])
        tree.links.new(ramp.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
        return material, "wood table"
    if kind == "steel":
        grey = rng.uniform(0.5, 0.75)
        roughness = rng.uniform(0.2, 0.5)
        material = principled("table", linear((grey, grey, grey)), 1.0, roughness)
        noise_into(material, rng, 30, max(0.05, roughness - 0.15), min(1.0, roughness + 0.2),
                   material.node_tree.nodes["Principled BSDF"].inputs["Roughness"],
                   stretch=(1, 60, 1))
        return material, f"steel table (grey {grey:.2f})"
    if kind == "painted":
        colour = drawn_colour(rng, *rng.choice([
            ((0, 360), (0.0, 0.08), (0.3, 0.9)),       # greys and white
            ((90, 150), (0.25, 0.55), (0.3, 0.6)),     # machine green
            ((200, 230), (0.3, 0.7), (0.3, 0.7)),      # blue
            ((20, 50), (0.6, 0.9), (0.6, 0.95))]))     # orange and yellow
        material = principled("table", linear(colour), 0.0, rng.uniform(0.25, 0.65))
        if rng.random() < 0.5:
            dusty(material, rng, colour)
        return material, f"painted table ({', '.join(f'{c:.2f}' for c in colour)})"
    grey = rng.uniform(0.03, 0.08)
    return principled("table", (grey, grey, grey), 0.0, rng.uniform(0.75, 0.95)), "rubber mat"


def random_rotation(rng):
    # a uniformly distributed unit quaternion (Shoemake)
    u1, u2, u3 = rng.random(), rng.random(), rng.random()
    q = mathutils.Quaternion((math.sqrt(u1) * math.cos(2 * math.pi * u3),
                              math.sqrt(1 - u1) * math.sin(2 * math.pi * u2),
                              math.sqrt(1 - u1) * math.cos(2 * math.pi * u2),
                              math.sqrt(u1) * math.sin(2 * math.pi * u3)))
    return q.to_matrix().to_4x4()


def add_rigid_body_world(scene, frames=300):
    """Blender's Bullet world: 30 substeps per frame, 30 iterations, 300 frames (12.5 s: the fall
    and the settling; the wider recipes, up to 16 parts, 480: 20 s)."""
    bpy.ops.rigidbody.world_add()
    world_rb = scene.rigidbody_world
    world_rb.substeps_per_frame = 30
    world_rb.solver_iterations = 30
    scene.frame_start = 1
    scene.frame_end = frames
    world_rb.point_cache.frame_start = 1
    world_rb.point_cache.frame_end = frames


def add_bin(size, material):
    """A box bin of size (inner length, inner width, inner height, wall; metres) whose inner
    floor's centre is the origin, and walls only the physics sees, up to 300 mm above its rim, so
    no part bounces out while the pile forms (a drop whose parts rest above the real rim is
    refused); returns the bin's boxes."""
    length, width, height, wall = size
    parts_of_bin = [
        box("bin_floor", (length + 2 * wall, width + 2 * wall, wall), (0, 0, -wall / 2)),
        box("bin_wall_x0", (wall, width + 2 * wall, height), (-(length + wall) / 2, 0, height / 2)),
        box("bin_wall_x1", (wall, width + 2 * wall, height), ((length + wall) / 2, 0, height / 2)),
        box("bin_wall_y0", (length, wall, height), (0, -(width + wall) / 2, height / 2)),
        box("bin_wall_y1", (length, wall, height), (0, (width + wall) / 2, height / 2)),
    ]
    for o in parts_of_bin:
        o.data.materials.append(material)
        o.pass_index = FLOOR_INDEX if o.name == "bin_floor" else WALLS_INDEX
    for name, size, location in [
            ("fence_x0", (wall, width + 2 * wall, 0.3), (-(length + wall) / 2, 0, height + 0.15)),
            ("fence_x1", (wall, width + 2 * wall, 0.3), ((length + wall) / 2, 0, height + 0.15)),
            ("fence_y0", (length, wall, 0.3), (0, -(width + wall) / 2, height + 0.15)),
            ("fence_y1", (length, wall, 0.3), (0, (width + wall) / 2, height + 0.15))]:
        fence = box(name, size, location)
        fence.hide_render = True
    return parts_of_bin


def add_table(wall, material):
    table = box("table", (2.0, 2.0, 0.02), (0, 0, -wall - 0.01))
    table.data.materials.append(material)
    table.pass_index = TABLE_INDEX
    return table


def add_bin_and_table(rng, recipe):
    """The narrow recipe: the bin (200 x 150 x 100 mm inside, 8 mm walls) of a drawn colour and
    a table of a drawn grey. The others: a tote and a table of the recipe's kinds, the tote of a
    drawn size (190..240 x 140..180 x 80..120 mm inside, walls 3..10 mm). Returns the surfaces,
    the bin's size (metres) and a note."""
    if recipe is None:
        size = (200 * MM, 150 * MM, 100 * MM, 8 * MM)
        bin_material = principled(
            "bin", rng.choice([(0.03, 0.06, 0.2), (0.05, 0.05, 0.05), (0.2, 0.2, 0.2),
                               (0.02, 0.12, 0.04), (0.25, 0.08, 0.02)]),
            0.0, rng.uniform(0.35, 0.75))
        parts_of_bin = add_bin(size, bin_material)
        grey = rng.uniform(0.05, 0.5)
        table = add_table(size[3], principled("table", (grey, grey * 0.95, grey * 0.9), 0.0,
                                              rng.uniform(0.4, 0.9)))
        return parts_of_bin + [table], size, "narrow bin and table"
    size = (rng.uniform(190, 240) * MM, rng.uniform(140, 180) * MM, rng.uniform(80, 120) * MM,
            rng.uniform(3, 10) * MM)
    tote, tote_note = tote_material(rng, rng.choice(recipe["totes"]))
    top, table_note = table_material(rng, rng.choice(recipe["tables"]))
    parts_of_bin = add_bin(size, tote)
    table = add_table(size[3], top)
    return parts_of_bin + [table], size, (
        f"{tote_note}, {size[0] / MM:.0f} x {size[1] / MM:.0f} x {size[2] / MM:.0f} mm, walls "
        f"{size[3] / MM:.1f} mm, on a {table_note}")


def add_parts(args, rng, scene, part_mesh, piece_meshes, recipe, size):
    """The connectors, each a compound of the convex pieces, released above the bin one above
    another: args.parts of one drawn roughness (narrow), or a drawn count (args.parts / 2 to
    args.parts * 4 / 3) of a drawn brightness and roughness; returns them and a note."""
    if recipe is None:
        aluminium = principled("aluminium", (0.80, 0.80, 0.82), 1.0, rng.uniform(0.2, 0.45),
                               noise_roughness=0.1)
        count, note = args.parts, f"{args.parts} parts"
    else:
        grey, roughness = rng.uniform(0.6, 0.9), rng.uniform(0.15, 0.6)
        aluminium = principled("aluminium", (grey, grey, grey * 1.02), 1.0, roughness,
                               noise_roughness=rng.uniform(0.05, 0.2))
        count = rng.randint(max(1, (args.parts + 1) // 2), max(1, args.parts * 4 // 3))
        note = f"{count} parts (grey {grey:.2f}, roughness {roughness:.2f})"
    # where they are released: over the floor, 40 mm above the rim and 60 mm apart (mm)
    spread_x, spread_y, rim = (50, 30, 100) if recipe is None else (
        size[0] / MM / 2 - 50, size[1] / MM / 2 - 45, size[2] / MM)
    parts = []
    for i in range(count):
        part = bpy.data.objects.new(f"part_{i + 1}", part_mesh)
        scene.collection.objects.link(part)
        part.data.materials.clear()
        part.data.materials.append(aluminium)
        part.pass_index = i + 1
        bpy.context.view_layer.objects.active = part
        part.select_set(True)
        bpy.ops.rigidbody.object_add(type="ACTIVE")
        part.rigid_body.collision_shape = "COMPOUND"
        part.rigid_body.mass = 0.0959  # 35,518 mm^3 of aluminium (2,700 kg/m^3)
        part.rigid_body.friction = 0.6
        part.rigid_body.restitution = 0.1
        part.rigid_body.use_margin = True
        part.rigid_body.collision_margin = 0.0005
        # damped a little, and asleep once slow, so a pile comes to rest instead of creeping
        part.rigid_body.linear_damping = 0.2
        part.rigid_body.angular_damping = 0.2
        part.rigid_body.use_deactivation = True
        part.rigid_body.deactivate_linear_velocity = 0.005
        part.rigid_body.deactivate_angular_velocity = 0.05
        part.select_set(False)
        # released above the bin, one above another, all at once
        part.matrix_world = mathutils.Matrix.Translation(
            (rng.uniform(-spread_x, spread_x) * MM, rng.uniform(-spread_y, spread_y) * MM,
             (rim + 40 + 60 * i) * MM)) @ \
            random_rotation(rng)
        for k, mesh in enumerate(piece_meshes):
            piece = bpy.data.objects.new(f"part_{i + 1}_piece_{k}", mesh)
            scene.collection.objects.link(piece)
            piece.parent = part
            piece.hide_render = True
            bpy.context.view_layer.objects.active = piece
            piece.select_set(True)
            bpy.ops.rigidbody.object_add(type="ACTIVE")
            piece.rigid_body.collision_shape = "CONVEX_HULL"
            piece.rigid_body.use_margin = True
            piece.rigid_body.collision_margin = 0.0005
            piece.select_set(False)
        parts.append(part)
    return parts, note


def add_camera(args, rng, scene, recipe):
    """The camera, aimed at the floor centre: 450 +- 30 mm from it, tilted up to 5 degrees,
    rolled +-10 (narrow); 410..530 mm, tilted up to 10 degrees, turned any way (the others).
    Returns the camera object and a note."""
    camera_data = bpy.data.cameras.new("camera")
    camera_data.sensor_fit = "HORIZONTAL"
    camera_data.sensor_width = 36.0
    camera_data.lens = args.fx * 36.0 / args.width
    camera_data.clip_start = 0.01
    camera = bpy.data.objects.new("camera", camera_data)
    scene.collection.objects.link(camera)
    scene.camera = camera
    near, far, most_tilt, most_roll = (420, 480, 5, 10) if recipe is None else (410, 530, 10, 180)
    distance = rng.uniform(near, far) * MM
    tilt = math.radians(rng.uniform(0, most_tilt))
    azimuth = rng.uniform(0, 2 * math.pi)
    eye = mathutils.Vector((distance * math.sin(tilt) * math.cos(azimuth),
                            distance * math.sin(tilt) * math.sin(azimuth),
                            distance * math.cos(tilt)))
    # Blender's camera looks along its -z with +y up in the image: image x along world x when
    # looking straight down, as stackgen's nominal pose
    back = eye.normalized()
    right = mathutils.Vector((0, 1, 0)).cross(back).normalized()
    up = back.cross(right)
    look = mathutils.Matrix((right, up, back)).transposed().to_4x4()
    roll = mathutils.Matrix.Rotation(math.radians(rng.uniform(-most_roll, most_roll)), 4, "Z")
    camera.matrix_world = mathutils.Matrix.Translation(eye) @ look @ roll
    return camera, f"camera {distance / MM:.0f} mm away, tilted {math.degrees(tilt):.1f} deg"


def add_environment(rng, scene, environments, strength):
    """An HDR environment of a drawn strength, turned at random: its file name."""
    world = bpy.data.worlds.new("world")
    scene.world = world
    world.use_nodes = True
    nodes = world.node_tree.nodes
    environment = nodes.new("ShaderNodeTexEnvironment")
    chosen = rng.choice(environments)
    environment.image = bpy.data.images.load(chosen)
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value = (0, 0, rng.uniform(0, 2 * math.pi))
    coordinates = nodes.new("ShaderNodeTexCoord")
    world.node_tree.links.new(coordinates.outputs["Generated"], mapping.inputs["Vector"])
    world.node_tree.links.new(mapping.outputs["Vector"], environment.inputs["Vector"])
    background = nodes["Background"]
    background.inputs["Strength"].default_value = rng.uniform(*strength)
    world.node_tree.links.new(environment.outputs["Color"], background.inputs["Color"])
    return os.path.basename(chosen)


def add_light(rng, scene, environments):
    """The narrow recipe's light: an HDR environment, and now and then a ceiling panel; returns
    a note."""
    chosen = add_environment(rng, scene, environments, (0.3, 1.0))
    panel = None
    if rng.random() < 0.5:
        light = bpy.data.lights.new("panel", "AREA")
        light.shape = "RECTANGLE"
        light.size = rng.uniform(0.3, 1.2)
        light.size_y = rng.uniform(0.1, 0.4)
        light.energy = rng.uniform(20, 100)
        panel = bpy.data.objects.new("panel", light)
        scene.collection.objects.link(panel)
        panel.location = (rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(1.0, 2.0))
    return f"environment {chosen}, ceiling panel {'yes' if panel else 'no'}"


def lamp(scene, name, kind, kelvin, location, target=(0, 0, 0)):
    """A light of a colour temperature (Blender's blackbody), at a place, aimed at target."""
    light = bpy.data.lights.new(name, kind)
    light.use_nodes = True
    nodes = light.node_tree.nodes
    blackbody = nodes.new("ShaderNodeBlackbody")
    blackbody.inputs["Temperature"].default_value = kelvin
    light.node_tree.links.new(blackbody.outputs["Color"], nodes["Emission"].inputs["Color"])
    o = bpy.data.objects.new(name, light)
    scene.collection.objects.link(o)
    o.location = location
    direction = mathutils.Vector(target) - mathutils.Vector(location)
    o.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()
    return o


def add_cell_lights(rng, scene, camera, recipe, environments):
    """One or two of the recipe's kinds of light over a dimmer HDR environment, each of a drawn
    colour temperature: LED strips (2-4 long thin panels 1.2-2.2 m up), a ceiling panel, a ring
    light around the lens, the sun (sharp shadows from 25-75 degrees up) or a window (a large
    panel 1.5-2.5 m away, low); returns a note."""
    notes = ["environment " + add_environment(rng, scene, environments, recipe["environment"])]
    for kind in rng.sample(recipe["lights"], rng.randint(1, 2)):
        kelvin = rng.uniform(*recipe["kelvin"])
        if kind == "strips":
            count = rng.randint(2, 4)
            turn = rng.uniform(0, math.pi)
            height = rng.uniform(1.2, 2.2)
            for k in range(count):
                offset = (k - (count - 1) / 2) * rng.uniform(0.3, 0.6)
                o = lamp(scene, f"strip_{k}", "AREA", kelvin,
                         (offset * math.cos(turn), offset * math.sin(turn), height),
                         (offset * math.cos(turn), offset * math.sin(turn), 0))
                o.data.shape = "RECTANGLE"
                o.data.size, o.data.size_y = rng.uniform(1.0, 1.5), rng.uniform(0.03, 0.06)
                o.rotation_euler.z += turn + math.pi / 2
                o.data.energy = rng.uniform(20, 80)
            notes.append(f"{count} LED strips {height:.1f} m up, {kelvin:.0f} K")
        elif kind == "panel":
            o = lamp(scene, "panel", "AREA", kelvin, (rng.uniform(-0.6, 0.6),
                                                      rng.uniform(-0.6, 0.6), rng.uniform(1.0, 2.0)))
            o.data.shape = "RECTANGLE"
            o.data.size, o.data.size_y = rng.uniform(0.3, 1.2), rng.uniform(0.1, 0.4)
            o.data.energy = rng.uniform(20, 100)
            notes.append(f"ceiling panel, {kelvin:.0f} K")
        elif kind == "ring":
            # a glowing torus around the lens, in the camera's image plane
            radius = rng.uniform(0.04, 0.09)
            bpy.ops.mesh.primitive_torus_add(major_radius=radius, minor_radius=0.006)
            ring = bpy.context.active_object
            ring.name = "ring_light"
            glow = bpy.data.materials.new("ring_light")
            glow.use_nodes = True
            tree = glow.node_tree
            tree.nodes.clear()
            emission = tree.nodes.new("ShaderNodeEmission")
            blackbody = tree.nodes.new("ShaderNodeBlackbody")
            blackbody.inputs["Temperature"].default_value = kelvin
            emission.inputs["Strength"].default_value = rng.uniform(10, 50)
            output = tree.nodes.new("ShaderNodeOutputMaterial")
            tree.links.new(blackbody.outputs["Color"], emission.inputs["Color"])
            tree.links.new(emission.outputs["Emission"], output.inputs["Surface"])
            ring.data.materials.append(glow)
            ring.parent = camera
            ring.matrix_world = camera.matrix_world.copy()
            notes.append(f"ring light {radius / MM:.0f} mm, {kelvin:.0f} K")
        elif kind == "sun":
            up, around = math.radians(rng.uniform(25, 75)), rng.uniform(0, 2 * math.pi)
            o = lamp(scene, "sun", "SUN", kelvin, (math.cos(up) * math.cos(around),
                                                    math.cos(up) * math.sin(around), math.sin(up)))
            o.data.energy = rng.uniform(1.5, 6.0)
            o.data.angle = math.radians(rng.uniform(0.5, 4))
            notes.append(f"sun {math.degrees(up):.0f} deg up, {kelvin:.0f} K")
        else:  # window
            up, around = math.radians(rng.uniform(10, 40)), rng.uniform(0, 2 * math.pi)
            distance = rng.uniform(1.5, 2.5)
            o = lamp(scene, "window", "AREA", kelvin,
                     (distance * math.cos(up) * math.cos(around),
                      distance * math.cos(up) * math.sin(around), distance * math.sin(up)))
            o.data.shape = "RECTANGLE"
            o.data.size, o.data.size_y = rng.uniform(1.0, 2.0), rng.uniform(0.8, 1.5)
            o.data.energy = rng.uniform(300, 1500)
            notes.append(f"window {math.degrees(up):.0f} deg up, {kelvin:.0f} K")
    return ", ".join(notes)


def build_scene(args, rng, part_mesh, piece_meshes, environments, recipe):
    """A bin, a table, the parts released above the bin, a camera, lights (in the file the
    meshes were just loaded into); returns the parts, the other surfaces, the bin's size and
    notes on what was drawn."""
    scene = bpy.context.scene
    add_rigid_body_world(scene, 300 if recipe is None else 480)
    surfaces, size, surroundings = add_bin_and_table(rng, recipe)
    parts, parts_note = add_parts(args, rng, scene, part_mesh, piece_meshes, recipe, size)
    camera, camera_note = add_camera(args, rng, scene, recipe)
    if recipe is None:
        light = add_light(rng, scene, environments)
        return parts, surfaces, size, light
    light = add_cell_lights(rng, scene, camera, recipe, environments)
    return parts, surfaces, size, "; ".join([surroundings, parts_note, camera_note, light])


def simulate(scene, parts):
    """Steps the rigid-body world to its end; returns the final poses and the largest motion of
    any part over the last second (24 frames; mm, degrees)."""
    poses = {}
    for frame in range(scene.frame_start, scene.frame_end + 1):
        scene.frame_set(frame)
        if frame in (scene.frame_end - 24, scene.frame_end):
            poses[frame] = [p.matrix_world.copy() for p in parts]
    moved_mm = 0.0
    turned_deg = 0.0
    for a, b in zip(poses[scene.frame_end - 24], poses[scene.frame_end]):
        moved_mm = max(moved_mm, (a.translation - b.translation).length / MM)
        difference = a.to_quaternion().rotation_difference(b.to_quaternion())
        angle = math.degrees(abs(difference.angle)) % 360
        turned_deg = max(turned_deg, min(angle, 360 - angle))
    return poses[scene.frame_end], moved_mm, turned_deg


def render_index(scene, path):
    """The object-index pass at each pixel's centre as an int array (rows top down)."""
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.pixel_filter_type = "BOX"
    scene.cycles.filter_width = 0.01
    scene.cycles.use_denoising = False
    scene.view_layers[0].use_pass_object_index = True
    scene.use_nodes = True
    tree = scene.node_tree
    tree.nodes.clear()
    layers = tree.nodes.new("CompositorNodeRLayers")
    output = tree.nodes.new("CompositorNodeOutputFile")
    output.base_path = os.path.dirname(path)
    output.file_slots[0].path = os.path.basename(path)
    output.format.file_format = "OPEN_EXR"
    output.format.color_depth = "32"
    tree.links.new(layers.outputs["IndexOB"], output.inputs[0])
    scene.render.filepath = path + "_discard"
    bpy.ops.render.render(write_still=False)
    written = glob.glob(path + "*.exr")
    image = bpy.data.images.load(written[0])
    pixels = np.array(image.pixels[:], dtype=np.float32).reshape(image.size[1], image.size[0], -1)
    bpy.data.images.remove(image)
    for f in written:
        os.remove(f)
    return np.rint(pixels[::-1, :, 0]).astype(np.int32)


def rle(mask):
    """COCO's uncompressed RLE: column-major runs, starting with the count of zeros."""
    flat = mask.flatten(order="F").astype(np.uint8)
    changes = np.flatnonzero(np.diff(flat)) + 1
    edges = np.concatenate(([0], changes, [flat.size]))
    counts = np.diff(edges).tolist()
    if flat[0] == 1:
        counts = [0] + counts
    return {"counts": counts, "size": [int(mask.shape[0]), int(mask.shape[1])]}


def load_meshes(args):
    """The part's mesh and its convex pieces, loaded into a fresh file (each scene)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    part_mesh = import_obj(args.mesh)[0].data
    part_mesh.use_fake_user = True
    piece_meshes = [o.data for o in import_obj(args.collision_mesh)]
    for m in piece_meshes:
        m.use_fake_user = True
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    return part_mesh, piece_meshes


def label(args, scene, parts, surroundings, work):
    """The labels: the visible ids at pixel centres, then each part alone (its full mask)."""
    scene.render.resolution_x = args.width
    scene.render.resolution_y = args.height
    scene.render.resolution_percentage = 100
    visible = render_index(scene, os.path.join(work, "index"))
    amodal = []
    for part in parts:
        for other in parts + surroundings:
            other.hide_render = other is not part
        amodal.append(render_index(scene, os.path.join(work, "alone")) == part.pass_index)
    for other in parts + surroundings:
        other.hide_render = False
    return visible, amodal


def render_picture(args, rng, scene, path, recipe):
    """The picture: Cycles, Filmic, the part's own noise (narrow). The others: an exposure and a
    tone curve (Filmic or Blender's plain clipping one) drawn, then the camera's own effects
    (apply_sensor). Returns a note."""
    scene.use_nodes = False
    scene.view_layers[0].use_pass_object_index = False
    scene.cycles.samples = args.samples
    scene.cycles.pixel_filter_type = "BLACKMAN_HARRIS"
    scene.cycles.filter_width = 1.5
    scene.cycles.seed = rng.randrange(1 << 30)
    scene.view_settings.view_transform = "Filmic"
    note = ""
    if recipe is not None:
        scene.view_settings.view_transform = rng.choice(["Filmic", "Standard"])
        scene.view_settings.exposure = rng.uniform(*recipe["exposure_ev"])
        note = (f"{scene.view_settings.view_transform}, exposure "
                f"{scene.view_settings.exposure:+.2f} EV")
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    if recipe is not None:
        note += ", " + apply_sensor(rng, path, recipe)
    return note


def blur(image, sigma):
    """A Gaussian blur of an (H, W, C) float image, separable, edges repeated."""
    radius = max(1, int(math.ceil(3 * sigma)))
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    taps /= taps.sum()
    for axis in (0, 1):
        padded = np.pad(image, [(radius, radius) if a == axis else (0, 0) for a in range(3)],
                        mode="edge")
        size = image.shape[axis]
        image = sum(w * np.take(padded, range(k, k + size), axis=axis) for k, w in enumerate(taps))
    return image


def apply_sensor(rng, path, recipe):
    """The camera's own effects on the written picture: defocus (a Gaussian blur of up to 1 px),
    a white balance off by up to 8 % per channel, shot noise (variance proportional to the
    linear signal) and read noise in linear light, then 8 bits again. Returns a note."""
    image = bpy.data.images.load(path)
    width, height = image.size
    pixels = np.array(image.pixels[:], dtype=np.float64).reshape(height, width, -1)[..., :3]
    bpy.data.images.remove(image)
    sigma = rng.uniform(0.0, 1.0)
    if sigma > 0.3:
        pixels = blur(pixels, sigma)
    gains = np.array([rng.uniform(0.92, 1.08) for _ in range(3)])
    shot, read = rng.uniform(*recipe["shot_noise"]), rng.uniform(*recipe["read_noise"])
    noise = np.random.default_rng(rng.randrange(1 << 32))
    signal = np.where(pixels <= 0.04045, pixels / 12.92, ((pixels + 0.055) / 1.055) ** 2.4)
    signal = signal * gains
    signal = signal + noise.normal(size=signal.shape) * np.sqrt(shot * np.maximum(signal, 0) +
                                                                read ** 2)
    signal = np.clip(signal, 0, 1)
    display = np.where(signal <= 0.0031308, signal * 12.92, 1.055 * signal ** (1 / 2.4) - 0.055)
    display = np.round(display * 255) / 255
    out = bpy.data.images.new("sensor", width, height, alpha=False)
    rgba = np.concatenate([display, np.ones((height, width, 1))], axis=2)
    out.pixels = rgba.astype(np.float32).ravel().tolist()
    out.filepath_raw = path
    out.file_format = "PNG"
    out.save()
    bpy.data.images.remove(out)
    return (f"blur {sigma if sigma > 0.3 else 0:.2f} px, white balance "
            f"{'/'.join(f'{g:.2f}' for g in gains)}, shot noise {shot:.4f}, read noise {read:.4f}")


def write_regions(path, visible):
    """The region map of a picture (8-bit PNG): 1 where the bin's floor is seen first, 2 its walls
    and rim, 0 elsewhere (parts, table, environment)."""
    regions = np.zeros(visible.shape, np.float32)
    for index, code in REGION_OF_INDEX.items():
        regions[visible == index] = code
    height, width = visible.shape
    image = bpy.data.images.new("regions", width, height, alpha=False)
    rgba = np.repeat(regions[::-1, :, None] / 255.0, 4, axis=2)
    rgba[..., 3] = 1.0
    image.pixels = rgba.ravel().tolist()
    image.filepath_raw = path
    image.file_format = "PNG"
    image.save()
    bpy.data.images.remove(image)


def pose_record(matrix):
    """A world-from-something pose (Blender, metres) as stackgen-coco writes one: translation in
    mm, row-major rotation."""
    return {"translation_mm": [round(v / MM, 6) for v in matrix.translation],
            "rotation": [round(matrix[r][c], 9) for r in range(3) for c in range(3)]}


def camera_record(args, camera):
    """The camera as stackgen-coco's image records hold it: fx, fy, cx, cy at pixel centres
    (OpenCV: the centre of pixel (u, v) is (u, v)) and world_from_camera with the camera looking
    along its z, x right and y down in the image (Blender's camera looks along its -z, y up)."""
    flip = mathutils.Matrix.Diagonal((1, -1, -1, 1))
    return {"fx": args.fx, "fy": args.fx, "cx": (args.width - 1) / 2, "cy": (args.height - 1) / 2,
            "world_from_camera": pose_record(camera.matrix_world @ flip)}


def annotate(coco, image_id, name, args, parts, visible, amodal, camera, size):
    """The image's COCO records (iscrowd 1 below 30 % visible; the full mask as
    amodal_segmentation, each part's pose as world_from_object; the camera and the bin's size in
    the image record); returns the parts annotated."""
    coco["images"].append({"id": image_id, "file_name": name, "width": args.width,
                           "height": args.height,
                           "stackgen": {"camera": camera_record(args, camera),
                                        "bin_size_mm": [round(v / MM, 3) for v in size]}})
    annotated = 0
    for k, part in enumerate(parts):
        mask = visible == part.pass_index
        area = int(mask.sum())
        full = int(amodal[k].sum())
        if area == 0 or full == 0:
            continue
        ys, xs = np.nonzero(mask)
        fraction = area / full
        coco["annotations"].append({
            "id": image_id * 1000 + k + 1, "image_id": image_id, "category_id": 1,
            "segmentation": rle(mask), "area": area,
            "bbox": [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1),
                     int(ys.max() - ys.min() + 1)],
            "iscrowd": 0 if fraction >= 0.3 else 1, "visib_fract": round(fraction, 4),
            "amodal_segmentation": rle(amodal[k]),
            "world_from_object": pose_record(part.matrix_world)})
        annotated += fraction >= 0.3
    return annotated


def write_dataset(args, coco, notes, work, out):
    """annotations.json and README.txt into `work`, then renamed to `out`."""
    with open(os.path.join(work, "annotations.json"), "w") as f:
        json.dump(coco, f)
    with open(os.path.join(work, "README.txt"), "w") as f:
        f.write(__doc__ + "\n")
        f.write(f"Made with Blender {bpy.app.version_string}: {args.count} scenes, recipe "
                f"{args.recipe}, seed {args.seed}, --parts {args.parts}, {args.samples} samples "
                "per pixel, "
                f"{args.width} x {args.height}, fx = fy = {args.fx} px.\n\n")
        f.write("\n".join(notes) + "\n")
    shutil.rmtree(out, ignore_errors=True)
    os.rename(work, out)


def main():
    args = parse_args()
    rng = random.Random(args.seed)
    environments = sorted(glob.glob(os.path.join(args.environments, "*.exr")) +
                          glob.glob(os.path.join(args.environments, "*.hdr")))
    if not environments:
        sys.exit(f"make-blender-testset: error: no .exr or .hdr file in {args.environments}")
    out = os.path.abspath(args.out)
    work = out + ".tmp"
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(os.path.join(work, "images"))

    coco = {"info": {"description": "independent test set made with Blender (research/make-blender-testset)"},
            "images": [], "annotations": [],
            "categories": [{"id": 1, "name": "corner_connector", "supercategory": "part"}]}
    notes = []
    scene_index = 0
    attempt = 0
    failures = 0
    recipe = RECIPES[args.recipe]
    os.makedirs(os.path.join(work, "regions"))
    while scene_index < args.count:
        attempt += 1
        start = time.time()
        part_mesh, piece_meshes = load_meshes(args)
        parts, surroundings, size, drawn = build_scene(args, rng, part_mesh, piece_meshes,
                                                       environments, recipe)
        scene = bpy.context.scene
        poses, moved_mm, turned_deg = simulate(scene, parts)

        # a pile at rest (every part moved less than 2 mm and 2 degrees over the last second), all
        # of it in the bin (a part may lean on the rim), or another drop
        inside = all(abs(p.translation.x) < size[0] / 2 and abs(p.translation.y) < size[1] / 2
                     and p.translation.z < size[2] - 10 * MM for p in poses)
        if moved_mm > 2.0 or turned_deg > 2.0 or not inside:
            failures += 1
            if failures == 30:
                sys.exit("make-blender-testset: error: 30 drops in a row did not come to rest in "
                         "the bin")
            print(f"make-blender-testset: drop {attempt}: moved {moved_mm:.2f} mm, "
                  f"{turned_deg:.2f} deg, inside {inside}; dropped again", flush=True)
            continue
        failures = 0
        bpy.ops.rigidbody.world_remove()
        for part, pose in zip(parts, poses):
            part.matrix_world = pose

        visible, amodal = label(args, scene, parts, surroundings, work)
        name = f"images/{scene_index:06d}.png"
        picture = render_picture(args, rng, scene, os.path.join(work, name), recipe)
        write_regions(os.path.join(work, "regions", f"{scene_index:06d}.png"), visible)
        annotated = annotate(coco, scene_index + 1, name, args, parts, visible, amodal,
                             scene.camera, size)
        notes.append(f"{name}: {drawn}{'; ' + picture if picture else ''}; pile moved "
                     f"{moved_mm:.2f} mm / {turned_deg:.2f} deg over its last second")
        print(f"make-blender-testset: scene {scene_index + 1}/{args.count}: {annotated} parts "
              f"annotated, {time.time() - start:.0f} s", flush=True)
        scene_index += 1

    write_dataset(args, coco, notes, work, out)
    print(f"make-blender-testset: wrote {out}/annotations.json: {len(coco['images'])} images, "
          f"{len(coco['annotations'])} annotations", flush=True)


if __name__ == "__main__":
    try:
        main()
    except SystemExit:
        raise
    except Exception as error:  # one line, then a non-zero exit from blender
        print(f"make-blender-testset: error: {error}", file=sys.stderr, flush=True)
        import traceback
        traceback.print_exc()
        sys.exit(1)
