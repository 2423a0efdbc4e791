"""The layered anatomical acetabulum (solver 0.5), meshed by gmsh with conforming layers.

Built with OpenCASCADE in the bone frame of :class:`thrsim.config.SocketConfig` (millimetres
inside gmsh, metres out): a ball of bone about the socket centre, cut by the rim's opening plane
and the medial wall's pelvic face; the cavity (the articular sphere and the fossa's recess); and
the layers, by fragmenting the block: an off-centre subchondral plate thicker under the dome and
the medial cortex, both cortical, the rest cancellous. Node sets: ``articular`` (the cavity face),
``medial_wall``, ``rim`` and ``supported`` (cuts through bone that continues: the mesh's fixed
nodes). The left hip is the mirror across x = 0. A window (``window_polar_deg``) keeps only the
bone within a cone about the socket centre, a piece the size of the thesis's patch; its cone
faces form ``window_side``, held like ``supported``. Dimensions and sources: the docs' Physics page.
"""

from __future__ import annotations

import math

import numpy as np

from thrsim.config import SocketConfig
from thrsim.geometry.gmsh_model import gmsh_session, read_back, set_mesh_options
from thrsim.geometry.mesh import ARTICULAR, CANCELLOUS, CORTICAL, MEDIAL_WALL, RIM, SUPPORTED, WINDOW_SIDE, TetMesh

#: how fast the element size grows away from the fine region (mm of size per mm of distance)
SIZE_GROWTH = 0.4


def dome_direction(config: SocketConfig) -> np.ndarray:
    """Unit vector from the socket centre to the superior dome (bone frame, right hip)."""
    angle = math.radians(config.dome_polar_deg)
    return np.array([0.0, math.sin(angle), -math.cos(angle)])


def fossa_axis(config: SocketConfig) -> np.ndarray:
    """Unit vector from the socket centre through the fossa's centre, into the bone (right hip)."""
    angle = math.radians(config.fossa_polar_deg)
    return np.array([0.0, -math.sin(angle), -math.cos(angle)])


def medial_wall_offset_mm(config: SocketConfig) -> float:
    """Distance of the medial wall's pelvic face from the socket centre, along the fossa's axis."""
    return config.socket_radius_mm + config.fossa_depth_mm + config.medial_wall_distance_mm


def window_area_mm2(radius_mm: float, half_angle_deg: float) -> float:
    """The area (mm²) of a window of the socket's sphere: the cap 2πr²(1 − cos h) of half-angle h at radius r."""
    return 2.0 * math.pi * radius_mm**2 * (1.0 - math.cos(math.radians(half_angle_deg)))


def generate_socket(config: SocketConfig | None = None) -> TetMesh:
    """Mesh the layered socket with gmsh (OpenCASCADE kernel) and return it in metres, materials tagged."""
    config = config or SocketConfig()
    radius = config.socket_radius_mm
    fossa = fossa_axis(config)
    wall = medial_wall_offset_mm(config)
    outer = config.fine_radius_mm + config.bone_stock_mm
    big = 4.0 * outer
    with gmsh_session("acetabular_socket") as gmsh:
        occ = gmsh.model.occ
        ball = occ.addSphere(0, 0, 0, outer)
        below_rim = occ.addBox(-big, -big, -big, 2 * big, 2 * big, big + config.rim_height_mm)
        block, _ = occ.intersect([(3, ball)], [(3, below_rim)])
        inside_wall = _half_space(occ, fossa, wall, big)
        block, _ = occ.intersect(block, [(3, inside_wall)])
        cavity = occ.addSphere(0, 0, 0, radius)
        recess_sphere = occ.addSphere(0, 0, 0, radius + config.fossa_depth_mm)
        cone_length = 2.0 * (radius + config.fossa_depth_mm)
        cone = occ.addCone(0, 0, 0, *(cone_length * fossa), 0, cone_length * math.tan(math.radians(config.fossa_half_angle_deg)))
        recess, _ = occ.intersect([(3, recess_sphere)], [(3, cone)])
        block, _ = occ.cut(block, [(3, cavity), *recess])
        window = config.window_direction
        if window is not None:
            length = 2.0 * outer
            sector = occ.addCone(0, 0, 0, *(length * np.array(window)), 0, length * math.tan(math.radians(config.window_half_angle_deg)))
            block, _ = occ.intersect(block, [(3, sector)])
        plate_centre = config.subchondral_dome_excess_mm * dome_direction(config)
        plate = occ.addSphere(*plate_centre, radius + config.subchondral_thickness_mm)
        cortex = _half_space(occ, -fossa, -(wall - config.medial_cortex_thickness_mm), big)
        pieces, _ = occ.fragment(block, [(3, plate), (3, cortex)])
        occ.synchronize()
        inside_block = _inside_block(config, fossa, wall, outer)
        keep, cortical = [], set()
        for dim, tag in gmsh.model.getEntities(3):
            centre = np.array(occ.getCenterOfMass(dim, tag))
            point = _interior_point(gmsh, tag, centre)
            if not inside_block(point):
                continue
            keep.append(tag)
            in_plate = np.linalg.norm(point - plate_centre) < radius + config.subchondral_thickness_mm
            in_cortex = float(point @ fossa) > wall - config.medial_cortex_thickness_mm
            if in_plate or in_cortex:
                cortical.add(tag)
        stray = [(3, tag) for _, tag in gmsh.model.getEntities(3) if tag not in keep]
        if stray:
            occ.remove(stray, recursive=True)
            occ.synchronize()
        faces = _classify_faces(gmsh, occ, config, fossa, wall, outer)
        set_mesh_options(gmsh, config.coarse_element_size_mm, config.min_element_size_mm)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        _size_field(gmsh, config, fossa, wall)
        gmsh.model.mesh.generate(3)
        built = read_back(gmsh, faces)

    names = (CORTICAL, CANCELLOUS)
    material = np.where(np.isin(built.volume_tag, sorted(cortical)), 0, 1).astype(np.uint8)
    mesh = TetMesh(
        nodes=built.nodes_m,
        tets=built.tets,
        node_sets=built.node_sets,
        fixed_nodes=built.node_sets[SUPPORTED] if window is None else np.union1d(built.node_sets[SUPPORTED], built.node_sets[WINDOW_SIDE]),
        material=material,
        material_names=names,
    )
    return mesh.mirrored(axis=0) if config.side == "left" else mesh


def _half_space(occ, normal: np.ndarray, offset: float, big: float) -> int:
    """A box standing for {p : p·normal ≤ offset} within ``big`` of the origin."""
    box = occ.addBox(-big, -big, -2 * big, 2 * big, 2 * big, 2 * big + offset)
    # turn the box's +z onto ``normal``: about the axis z × normal by the angle between them
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, normal)
    sin_angle, cos_angle = float(np.linalg.norm(axis)), float(z @ normal)
    if sin_angle > 1e-12:
        occ.rotate([(3, box)], 0, 0, 0, *axis, math.atan2(sin_angle, cos_angle))
    elif cos_angle < 0:
        occ.rotate([(3, box)], 0, 0, 0, 1, 0, 0, math.pi)
    return box


def _inside_block(config: SocketConfig, fossa: np.ndarray, wall: float, outer: float):
    """Whether a point (mm) lies in the bone block: a test for the fragments OCC leaves outside it."""
    radius = config.socket_radius_mm

    def inside(point: np.ndarray) -> bool:
        r = float(np.linalg.norm(point))
        if r >= outer or point[2] >= config.rim_height_mm or float(point @ fossa) >= wall:
            return False
        in_recess = r < radius + config.fossa_depth_mm and float(point @ fossa) > r * math.cos(math.radians(config.fossa_half_angle_deg))
        window = config.window_direction
        if window is not None and float(point @ np.array(window)) < r * math.cos(math.radians(config.window_half_angle_deg)):
            return False
        return r > radius and not in_recess

    return inside


def _interior_point(gmsh, tag: int, centre: np.ndarray) -> np.ndarray:
    """A point inside volume ``tag``: its centre of mass when inside (convex pieces), else a point
    found by bisecting toward a point on one of its faces."""
    if gmsh.model.isInside(3, tag, list(centre)):
        return centre
    for _, face in gmsh.model.getBoundary([(3, tag)], oriented=False):
        bounds = gmsh.model.getParametrizationBounds(2, face)
        middle = [0.5 * (lo + hi) for lo, hi in zip(bounds[0], bounds[1], strict=True)]
        on_face = np.array(gmsh.model.getValue(2, face, middle))
        for weight in (0.02, 0.05, 0.1, 0.2):
            trial = on_face + weight * (centre - on_face)
            if gmsh.model.isInside(3, tag, list(trial)):
                return trial
    return centre


def _classify_faces(gmsh, occ, config: SocketConfig, fossa: np.ndarray, wall: float, outer: float) -> dict[str, list[int]]:
    """The bone's outer faces by what they are: cavity (articular), pelvic face, rim plane, support."""
    faces: dict[str, list[int]] = {ARTICULAR: [], MEDIAL_WALL: [], RIM: [], SUPPORTED: [], WINDOW_SIDE: []}
    volumes = gmsh.model.getEntities(3)
    boundary = gmsh.model.getBoundary(volumes, combined=True, oriented=False)
    cavity_limit = config.socket_radius_mm + config.fossa_depth_mm + 1e-3
    for _, tag in boundary:
        centre = np.array(occ.getCenterOfMass(2, tag))
        kind = gmsh.model.getType(2, tag)
        if kind == "Plane" and abs(centre[2] - config.rim_height_mm) < 1e-6:
            faces[RIM].append(tag)
        elif kind == "Plane" and abs(float(centre @ fossa) - wall) < 1e-6:
            faces[MEDIAL_WALL].append(tag)
        elif _max_radius(gmsh, tag) <= cavity_limit:
            faces[ARTICULAR].append(tag)
        elif kind == "Cone" and config.window_direction is not None:
            faces[WINDOW_SIDE].append(tag)
        elif kind == "Sphere" and abs(_max_radius(gmsh, tag) - outer) < 1e-3:
            faces[SUPPORTED].append(tag)
        else:
            faces[SUPPORTED].append(tag)
    return faces


def _max_radius(gmsh, tag: int) -> float:
    """Largest distance from the socket centre over the corners of a face's bounding box... of its
    sampled points: the face's reach."""
    bounds = gmsh.model.getParametrizationBounds(2, tag)
    u = np.linspace(bounds[0][0], bounds[1][0], 7)
    v = np.linspace(bounds[0][1], bounds[1][1], 7)
    grid = [value for uu in u for vv in v for value in (uu, vv)]
    points = np.asarray(gmsh.model.getValue(2, tag, grid)).reshape(-1, 3)
    return float(np.linalg.norm(points, axis=1).max())


def _size_field(gmsh, config: SocketConfig, fossa: np.ndarray, wall: float) -> None:
    """Element size: fine within the planned reamers' reach and behind the fossa out to the medial
    wall, growing by ``SIZE_GROWTH`` per mm beyond, capped at the coarse size."""
    fine, coarse = config.element_size_mm, config.coarse_element_size_mm
    reach = config.fine_radius_mm
    r = "Sqrt(x*x+y*y+z*z)"
    along = "({}*x+{}*y+{}*z)".format(*(f"({float(c):.15g})" for c in fossa))
    lateral = f"Sqrt(Max(0,x*x+y*y+z*z-{along}*{along}))"
    fossa_reach = (config.socket_radius_mm + config.fossa_depth_mm) * math.sin(math.radians(config.fossa_half_angle_deg))
    fossa_reach += config.fine_margin_mm
    field = gmsh.model.mesh.field
    sphere = field.add("MathEval")
    field.setString(sphere, "F", f"Min({coarse},{fine}+{SIZE_GROWTH}*Max(0,{r}-{reach}))")
    behind = field.add("MathEval")
    field.setString(behind, "F", f"Min({coarse},{fine}+{SIZE_GROWTH}*(Max(0,{lateral}-{fossa_reach})+Max(0,{along}-{wall})))")
    smallest = field.add("Min")
    field.setNumbers(smallest, "FieldsList", [sphere, behind])
    field.setAsBackgroundMesh(smallest)
