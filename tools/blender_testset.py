"""An independent test set for stackgen: piles made and rendered another way, inside Blender.

Run by tools/make-blender-testset (blender --background --factory-startup --python this file --
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
    return parser.parse_args(argv)


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


def random_rotation(rng):
    # a uniformly distributed unit quaternion (Shoemake)
    u1, u2, u3 = rng.random(), rng.random(), rng.random()
    q = mathutils.Quaternion((math.sqrt(u1) * math.cos(2 * math.pi * u3),
                              math.sqrt(1 - u1) * math.sin(2 * math.pi * u2),
                              math.sqrt(1 - u1) * math.cos(2 * math.pi * u2),
                              math.sqrt(u1) * math.sin(2 * math.pi * u3)))
    return q.to_matrix().to_4x4()


def add_rigid_body_world(scene):
    """Blender's Bullet world: 30 substeps per frame, 30 iterations, 300 frames (12.5 s: the fall
    and the settling)."""
    bpy.ops.rigidbody.world_add()
    world_rb = scene.rigidbody_world
    world_rb.substeps_per_frame = 30
    world_rb.solver_iterations = 30
    scene.frame_start = 1
    # 12.5 s: the fall and the settling
    frames = 300
    scene.frame_end = frames
    world_rb.point_cache.frame_start = 1
    world_rb.point_cache.frame_end = frames


def add_bin_and_table(rng):
    """The bin (200 x 150 x 100 mm inside, 8 mm walls) of a drawn colour, walls only the physics
    sees above it, and a table of a drawn grey: the surfaces drawn."""
    length, width, height, wall = 200 * MM, 150 * MM, 100 * MM, 8 * MM
    bin_material = principled(
        "bin", rng.choice([(0.03, 0.06, 0.2), (0.05, 0.05, 0.05), (0.2, 0.2, 0.2),
                           (0.02, 0.12, 0.04), (0.25, 0.08, 0.02)]),
        0.0, rng.uniform(0.35, 0.75))
    parts_of_bin = [
        box("bin_floor", (length + 2 * wall, width + 2 * wall, wall), (0, 0, -wall / 2)),
        box("bin_wall_x0", (wall, width + 2 * wall, height), (-(length + wall) / 2, 0, height / 2)),
        box("bin_wall_x1", (wall, width + 2 * wall, height), ((length + wall) / 2, 0, height / 2)),
        box("bin_wall_y0", (length, wall, height), (0, -(width + wall) / 2, height / 2)),
        box("bin_wall_y1", (length, wall, height), (0, (width + wall) / 2, height / 2)),
    ]
    for o in parts_of_bin:
        o.data.materials.append(bin_material)
    # walls seen by the physics only, up to 400 mm, so no part bounces out while the pile forms
    # (a drop whose parts rest above the real rim is refused)
    for name, size, location in [
            ("fence_x0", (wall, width + 2 * wall, 0.3), (-(length + wall) / 2, 0, height + 0.15)),
            ("fence_x1", (wall, width + 2 * wall, 0.3), ((length + wall) / 2, 0, height + 0.15)),
            ("fence_y0", (length, wall, 0.3), (0, -(width + wall) / 2, height + 0.15)),
            ("fence_y1", (length, wall, 0.3), (0, (width + wall) / 2, height + 0.15))]:
        fence = box(name, size, location)
        fence.hide_render = True
    table = box("table", (2.0, 2.0, 0.02), (0, 0, -wall - 0.01))
    grey = rng.uniform(0.05, 0.5)
    table.data.materials.append(principled("table", (grey, grey * 0.95, grey * 0.9), 0.0,
                                           rng.uniform(0.4, 0.9)))

    return parts_of_bin + [table]


def add_parts(args, rng, scene, part_mesh, piece_meshes):
    """args.parts connectors of drawn roughness, each a compound of the convex pieces, released
    above the bin one above another."""
    aluminium = principled("aluminium", (0.80, 0.80, 0.82), 1.0, rng.uniform(0.2, 0.45),
                           noise_roughness=0.1)
    parts = []
    for i in range(args.parts):
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
            (rng.uniform(-50, 50) * MM, rng.uniform(-30, 30) * MM, (140 + 60 * i) * MM)) @ \
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

    return parts


def add_camera(args, rng, scene):
    """The camera: 450 +- 30 mm above the floor centre, tilted up to 5 degrees, rolled +-10."""
    camera_data = bpy.data.cameras.new("camera")
    camera_data.sensor_fit = "HORIZONTAL"
    camera_data.sensor_width = 36.0
    camera_data.lens = args.fx * 36.0 / args.width
    camera_data.clip_start = 0.01
    camera = bpy.data.objects.new("camera", camera_data)
    scene.collection.objects.link(camera)
    scene.camera = camera
    distance = rng.uniform(420, 480) * MM
    tilt = math.radians(rng.uniform(0, 5))
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
    roll = mathutils.Matrix.Rotation(math.radians(rng.uniform(-10, 10)), 4, "Z")
    camera.matrix_world = mathutils.Matrix.Translation(eye) @ look @ roll


def add_light(rng, scene, environments):
    """An HDR environment, turned and scaled at random, and now and then a ceiling panel: the
    environment's file name and whether a panel shines."""
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
    background.inputs["Strength"].default_value = rng.uniform(0.3, 1.0)
    world.node_tree.links.new(environment.outputs["Color"], background.inputs["Color"])
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
    return os.path.basename(chosen), panel is not None


def build_scene(args, rng, part_mesh, piece_meshes, environments):
    """A bin, a table, 12 parts released above the bin, a camera, lights (in the file the meshes
    were just loaded into); returns the parts, the other surfaces, the environment and whether
    a ceiling panel shines."""
    scene = bpy.context.scene
    add_rigid_body_world(scene)
    surfaces = add_bin_and_table(rng)
    parts = add_parts(args, rng, scene, part_mesh, piece_meshes)
    add_camera(args, rng, scene)
    environment, panel = add_light(rng, scene, environments)
    return parts, surfaces, environment, panel


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


def render_picture(args, rng, scene, path):
    """The picture: Cycles, Filmic, the part's own noise."""
    scene.use_nodes = False
    scene.view_layers[0].use_pass_object_index = False
    scene.cycles.samples = args.samples
    scene.cycles.pixel_filter_type = "BLACKMAN_HARRIS"
    scene.cycles.filter_width = 1.5
    scene.cycles.seed = rng.randrange(1 << 30)
    scene.view_settings.view_transform = "Filmic"
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)


def annotate(coco, image_id, name, args, parts, visible, amodal):
    """The image's COCO records (iscrowd 1 below 30 % visible); returns the parts annotated."""
    coco["images"].append({"id": image_id, "file_name": name, "width": args.width,
                           "height": args.height})
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
            "iscrowd": 0 if fraction >= 0.3 else 1, "visib_fract": round(fraction, 4)})
        annotated += fraction >= 0.3
    return annotated


def write_dataset(args, coco, notes, work, out):
    """annotations.json and README.txt into `work`, then renamed to `out`."""
    with open(os.path.join(work, "annotations.json"), "w") as f:
        json.dump(coco, f)
    with open(os.path.join(work, "README.txt"), "w") as f:
        f.write(__doc__ + "\n")
        f.write(f"Made with Blender {bpy.app.version_string}: {args.count} scenes, seed "
                f"{args.seed}, {args.parts} parts, {args.samples} samples per pixel, "
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

    coco = {"info": {"description": "independent test set made with Blender (tools/make-blender-testset)"},
            "images": [], "annotations": [],
            "categories": [{"id": 1, "name": "corner_connector", "supercategory": "part"}]}
    notes = []
    scene_index = 0
    attempt = 0
    failures = 0
    while scene_index < args.count:
        attempt += 1
        start = time.time()
        part_mesh, piece_meshes = load_meshes(args)
        parts, surroundings, environment, panel = build_scene(args, rng, part_mesh, piece_meshes,
                                                              environments)
        scene = bpy.context.scene
        poses, moved_mm, turned_deg = simulate(scene, parts)

        # a pile at rest (every part moved less than 2 mm and 2 degrees over the last second), all
        # of it in the bin (a part may lean on the rim), or another drop
        inside = all(abs(p.translation.x) < 0.1 and abs(p.translation.y) < 0.075 and
                     p.translation.z < 0.09 for p in poses)
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
        render_picture(args, rng, scene, os.path.join(work, name))
        annotated = annotate(coco, scene_index + 1, name, args, parts, visible, amodal)
        notes.append(f"{name}: environment {environment}, ceiling panel {'yes' if panel else 'no'}, "
                     f"pile moved {moved_mm:.2f} mm / {turned_deg:.2f} deg over its last second")
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
