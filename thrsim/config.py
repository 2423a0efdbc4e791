"""Validated configuration, with units. The defaults are the numbers of the source thesis, "Machine
Learning and Interactive Real-Time Simulation for Training on Relevant Total Hip Replacement
Skills" (its section, table or equation in brackets), unless a docstring says why one differs.

Inside, quantities are SI (m, kg, s, N, Pa, rad) unless a field name says otherwise
(``_mm``, ``_deg``): those are user-facing values, converted once by the properties here.
A bad value (negative size, inclination outside [0, 90], unknown side, NaN or infinity anywhere)
raises pydantic's ``ValidationError``, which the CLI reports as one line.
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, IPvAnyNetwork, field_validator, model_validator

from thrsim import portable_math as pm

#: the operated hip; a left hip is the mirror of a right one (:func:`thrsim.nav.bone_frame.on_side`)
Side = Literal["right", "left"]
SIDES: tuple[Side, ...] = get_args(Side)


#: frames per second of reaming: the thesis's cases, the learned simulator's steps and the trainer's
#: tick (:class:`ReamingCaseConfig`, :class:`SweepConfig`, ``thrsim serve``, ``thrsim ream``)
FRAME_RATE_HZ = 60.0
#: the surgeon's axial push along the reamer axis, the thesis's mean [5.3.2]: the default of a case,
#: a sweep, ``thrsim ream`` and the trainer's force control
PUSH_FORCE_N = 230.0


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


#: an output frame rate a case or sweep may ask for (the thesis's is 60 Hz); far outside, a frame
#: is shorter than a solver step or longer than any reaming
FrameRateHz = Annotated[float, Field(ge=1.0, le=10_000.0)]
#: output frames a case or sweep may ask for: 100,000 frames at 60 Hz are 28 minutes of reaming
FrameCount = Annotated[int, Field(ge=1, le=100_000)]


class BonePatchConfig(_Frozen):
    """Spherical-shell patch of acetabular cortical bone around the cavity pole [5.1.1].

    The thesis's block shape is not given; the default shell (inner radius 22 mm) with the
    thickness and half-angle below gives 20,406 ± 10 % linear tets at the thesis's global size
    0.45 mm (minimum size 0.045 mm).
    """

    inner_radius_mm: float = Field(22.0, gt=0, le=100.0, description="articular (reamed) face radius")
    thickness_mm: float = Field(2.0, gt=0, le=50.0, description="shell thickness, inner to outer face")
    half_angle_deg: float = Field(19.0, gt=0, lt=90, description="patch half-angle about the pole")
    element_size_mm: float = Field(0.45, ge=0.1, le=10.0, description="global element size [Table 5]")
    min_element_size_mm: float = Field(0.045, ge=0.01, description="minimum element size [Table 5]")
    side: Side = "right"
    support_side_faces: bool = Field(
        True,
        description="hold the side faces on an elastic foundation standing for the bone that continues "
        "beyond the cut (a rigid support would make an uncuttable ring the reamer rests on)",
    )

    @model_validator(mode="after")
    def _sizes_consistent(self) -> BonePatchConfig:
        if self.min_element_size_mm > self.element_size_mm:
            raise ValueError("min_element_size_mm must not exceed element_size_mm")
        if self.element_size_mm > self.thickness_mm * 4:
            raise ValueError("element_size_mm is far larger than the shell thickness")
        return self

    @property
    def inner_radius(self) -> float:
        return self.inner_radius_mm * 1e-3

    @property
    def outer_radius(self) -> float:
        return (self.inner_radius_mm + self.thickness_mm) * 1e-3

    @property
    def half_angle(self) -> float:
        return math.radians(self.half_angle_deg)


class SocketConfig(_Frozen):
    """The layered anatomical acetabulum (solver 0.5), in the bone frame of the right hip.

    Bone frame: origin at the centre of the native socket's sphere, +z out of the socket along its
    axis, +y toward the superior dome, +x = y × z (anterior for the right hip; the left hip is the
    mirror across x = 0). The socket is a hemisphere opening at the plane z = ``rim_height_mm``;
    the acetabular fossa is a recess of the floor centred ``fossa_polar_deg`` from the pole toward
    inferior (−y); the medial wall (quadrilateral plate) is a plane normal to the fossa's axis,
    ``medial_wall_distance_mm`` behind the fossa floor, with a cortical layer on its pelvic face; the
    subchondral plate is a cortical layer under the articular surface, thicker under the dome. The
    rest is cancellous. Dimensions and their sources: docs, "The anatomical socket".

    The mesh is fine (``element_size_mm``) wherever a reamer up to ``planned_reamer_max_mm`` can cut
    (its teeth plus ``fine_margin_mm``) and in the bone behind the fossa out to the medial wall; it
    grows to ``coarse_element_size_mm`` beyond.
    """

    socket_diameter_mm: float = Field(46.0, ge=40.0, le=60.0, description="native socket (articular sphere) diameter")
    planned_reamer_max_mm: float | None = Field(
        None, gt=0, le=100.0, description="largest reamer the fine mesh is made for; None = socket diameter + 4 mm"
    )
    fine_margin_mm: float = Field(1.0, ge=0, le=20.0, description="fine mesh beyond the largest planned reamer's teeth")
    rim_height_mm: float = Field(0.0, ge=-10.0, le=10.0, description="opening plane's height above the socket centre")
    bone_stock_mm: float = Field(8.0, gt=0, le=50.0, description="bone beyond the largest planned reamer, to the supported boundary")
    subchondral_thickness_mm: float = Field(1.5, gt=0, le=10.0, description="subchondral plate thickness, mean over the socket")
    subchondral_dome_excess_mm: float = Field(1.0, ge=0, le=10.0, description="extra plate thickness under the dome (less opposite)")
    dome_polar_deg: float = Field(35.0, ge=0, lt=90, description="the dome's direction: this far from the pole toward superior")
    fossa_depth_mm: float = Field(3.0, gt=0, le=20.0, description="how far the fossa floor lies below the articular sphere")
    fossa_half_angle_deg: float = Field(30.0, gt=0, lt=60, description="angular radius of the fossa about its centre")
    fossa_polar_deg: float = Field(25.0, ge=0, lt=60, description="the fossa's centre: this far from the pole toward inferior")
    medial_wall_distance_mm: float = Field(4.0, gt=0, le=30.0, description="bone from the fossa floor to the medial wall's pelvic face")
    medial_cortex_thickness_mm: float = Field(1.0, gt=0, le=10.0, description="cortical layer on the medial wall's pelvic face")
    window_polar_deg: float | None = Field(
        None, ge=0, le=90, description="mesh only a window of the socket: its centre this far from the pole (None: the whole socket)"
    )
    window_azimuth_deg: float = Field(
        90.0, ge=-360, le=360, description="the window's direction about the socket axis, from anterior (+x) toward superior (+y)"
    )
    window_half_angle_deg: float = Field(10.0, gt=0, le=45, description="the window's angular radius about the socket centre")
    element_size_mm: float = Field(0.45, ge=0.1, le=10.0, description="element size where a planned reamer can cut [Table 5]")
    coarse_element_size_mm: float = Field(3.0, ge=0.1, le=20.0, description="element size far from the cutting")
    min_element_size_mm: float = Field(0.045, ge=0.01, description="minimum element size [Table 5]")
    side: Side = "right"

    @model_validator(mode="after")
    def _consistent(self) -> SocketConfig:
        if self.min_element_size_mm > self.element_size_mm:
            raise ValueError("min_element_size_mm must not exceed element_size_mm")
        if self.coarse_element_size_mm < self.element_size_mm:
            raise ValueError("coarse_element_size_mm must not be below element_size_mm")
        if self.subchondral_dome_excess_mm >= self.subchondral_thickness_mm:
            raise ValueError("subchondral_dome_excess_mm must be below subchondral_thickness_mm (the plate would vanish opposite the dome)")
        if self.medial_cortex_thickness_mm >= self.medial_wall_distance_mm:
            raise ValueError("medial_cortex_thickness_mm must be below medial_wall_distance_mm")
        if self.planned_reamer_max_mm is not None and self.planned_reamer_max_mm < self.socket_diameter_mm - 10.0:
            raise ValueError("planned_reamer_max_mm is far below the socket diameter")
        return self

    @property
    def socket_radius_mm(self) -> float:
        return 0.5 * self.socket_diameter_mm

    @property
    def window_direction(self) -> tuple[float, float, float] | None:
        """Unit vector from the socket centre through the window's centre (right hip), None for the whole socket."""
        if self.window_polar_deg is None:
            return None
        polar, azimuth = math.radians(self.window_polar_deg), math.radians(self.window_azimuth_deg)
        return (math.sin(polar) * math.cos(azimuth), math.sin(polar) * math.sin(azimuth), -math.cos(polar))

    @property
    def planned_reamer_max_diameter_mm(self) -> float:
        return self.planned_reamer_max_mm if self.planned_reamer_max_mm is not None else self.socket_diameter_mm + 4.0

    @property
    def fine_radius_mm(self) -> float:
        """Radius about the socket centre within which a planned reamer's teeth can cut, plus the margin:
        the bone stock the fine mesh is made for."""
        return 0.5 * self.planned_reamer_max_diameter_mm + ReamerConfig.model_fields["tooth_protrusion_mm"].default + self.fine_margin_mm


class BoneMaterial(_Frozen):
    """Elastic constants of cortical bone [Table 7]."""

    density_kg_m3: float = Field(1700.0, gt=0, le=1e5)
    youngs_modulus_pa: float = Field(17e9, gt=0, le=1e13)
    poisson_ratio: float = Field(0.35, gt=-1.0, lt=0.5)

    @property
    def shear_modulus_pa(self) -> float:
        return self.youngs_modulus_pa / (2 * (1 + self.poisson_ratio))

    @property
    def lame_lambda_pa(self) -> float:
        nu = self.poisson_ratio
        return self.youngs_modulus_pa * nu / ((1 + nu) * (1 - 2 * nu))

    @property
    def bulk_modulus_pa(self) -> float:
        return self.youngs_modulus_pa / (3 * (1 - 2 * self.poisson_ratio))

    @property
    def dilatational_wave_speed_m_s(self) -> float:
        return math.sqrt((self.lame_lambda_pa + 2 * self.shear_modulus_pa) / self.density_kg_m3)


class JohnsonCookHardening(_Frozen):
    """``σ_y = [A + B εᵖⁿ][1 + C ln(ε̇ᵖ/ε̇₀)]``; thermal softening off [Table 4]."""

    a_pa: float = Field(50e6, gt=0)
    b_pa: float = Field(101e6, ge=0)
    n: float = Field(0.08, gt=0)
    c: float = Field(0.03, ge=0)
    reference_strain_rate_s: float = Field(1e-3, gt=0)
    thermal_m: float = Field(0.02, ge=0, description="listed in the thesis, unused (no heating)")


class JohnsonCookDamage(_Frozen):
    """``ε_f = [d1 + d2 exp(d3 η)][1 + d4 ln(ε̇ᵖ/ε̇₀)]`` initiation, linear evolution in u = L_e Δεᵖ.

    With the thesis constants ε_f < 0 for every triaxiality η: damage initiates at first yield.
    ``displacement_at_failure_m`` (u_f): Table 8 lists 5e-4 m, the text [5.2.1] 1e-4 m. The
    default, 4.5e-4 m, was calibrated with solver 0.2.0; since 0.3.0 the teeth's cutting law
    (:class:`ContactConfig`, ``specific_cutting_energy_j_m3``) sets the pace of the default case
    and this damage adds to it (docs/benchmarks.md, "Calibration").
    """

    d1: float = -0.09
    d2: float = 0.08
    d3: float = 0.006
    d4: float = 0.0
    d5: float = Field(0.01, description="thermal term, unused")
    displacement_at_failure_m: float = Field(4.5e-4, ge=1e-6, le=1.0)

    TABLE_8_U_F_M: ClassVar[float] = 5e-4
    TEXT_U_F_M: ClassVar[float] = 1e-4


#: the thesis's reamer: 56 teeth on a 45 mm head [5.1.2]; other sizes keep its teeth per mm of diameter
REFERENCE_REAMER_DIAMETER_MM, REFERENCE_TOOTH_COUNT = 45.0, 56


def teeth_for_diameter(head_diameter_mm: float) -> int:
    """Tooth count of a reamer of this size: the thesis reamer's teeth per millimetre of diameter.

    Keeping the teeth's spacing along the head keeps the number of teeth that sweep each point of
    the profile per turn (5–6, :mod:`thrsim.geometry.reamer`) the same at every size, so a size's
    cutting rate per unit area does not depend on a tooth count chosen for it. The thesis gives
    30–60 teeth across sizes [5.1.2]; this rule gives 50 at 40 mm and 80 at 64 mm.
    """
    return max(1, round(REFERENCE_TOOTH_COUNT * head_diameter_mm / REFERENCE_REAMER_DIAMETER_MM))


class CrushableFoam(_Frozen):
    """Compaction of crushed trabecular bone: Deshpande–Fleck's isotropic crushable foam.

    Yield surface √(q² + α²p²) = √(1 + α²/9)·σ_c(ε̂), associated flow, hardening in the uniaxial
    compressive plastic strain ε̂ (Deshpande & Fleck, J Mech Phys Solids 2000; ABAQUS's isotropic
    crushable foam): the bone's JC curve as plateau, times Gibson and Ashby's densification
    (1/D)·(ε_D/(ε_D − ε̂))^m once that exceeds 1, with ε_D = 1 − 1.4·ρ/ρ_s (Cellular Solids, 1997),
    up to the tissue's own strength; there the bone is fully dense, and it fractures as solid bone.
    Plastic Poisson ratio 0 (α = 3/√2): crushed cellular solids barely spread sideways (Gibson &
    Ashby; Deshpande & Fleck). Confidence: low to moderate (the form is standard for trabecular bone
    and metal foams; ν_p, D and m are the generic foam values, not fitted to acetabular bone).
    """

    plastic_poisson_ratio: float = Field(0.0, ge=0.0, lt=0.5, description="ν_p: lateral over axial plastic strain in uniaxial crushing")
    tissue_density_kg_m3: float = Field(1900.0, gt=0, le=1e5, description="ρ_s of the bone tissue the trabeculae are made of")
    densification_coefficient: float = Field(2.3, ge=1.0, le=100.0, description="D of Gibson and Ashby's densification law")
    densification_exponent: float = Field(1.0, gt=0.0, le=10.0, description="m of Gibson and Ashby's densification law")
    densified_flow_stress_pa: float = Field(
        JohnsonCookHardening.model_fields["a_pa"].default,
        gt=0.0,
        le=1e10,
        description="σ_c's ceiling: crushed bone is no stronger than the tissue it is made of (the cortical yield A)",
    )

    @property
    def yield_ellipse_alpha(self) -> float:
        """α of the yield ellipse from ν_p: α² = 9(1 − 2ν_p) / (2(1 + ν_p))."""
        nu = self.plastic_poisson_ratio
        return math.sqrt(4.5 * (1.0 - 2.0 * nu) / (1.0 + nu))

    def densification_strain(self, apparent_density_kg_m3: float) -> float:
        """ε_D = 1 − 1.4·ρ/ρ_s, the crushing strain at which the cells are fully collapsed."""
        return 1.0 - 1.4 * apparent_density_kg_m3 / self.tissue_density_kg_m3


class CancellousBone(_Frozen):
    """Cancellous (trabecular) bone behind the socket's subchondral plate: one material of the socket.

    Defaults: normal acetabular cancellous bone, apparent density 0.5 g/cm³. Elastic modulus from
    the pelvic trabecular bone modulus–density law E ≈ 2017·ρ^2.46 MPa (Dalstra et al., J Biomech Eng
    1993); yield at the ≈ 0.75 % compressive yield strain that trabecular bone shares across densities
    (Morgan & Keaveny, J Biomech 2003), so A = 0.0075·E; hardening B/A and n as the thesis's cortical
    bone (Table 4), rate sensitivity as cortical. Crushed, it compacts (:class:`CrushableFoam`) and
    never fractures; in shear or tension damage initiates at 50 % plastic strain, so the teeth's
    cutting, not crushing under the push, removes it. Its specific cutting energy is a fifth of the
    cortical default (drilling and cutting studies find cancellous bone several times easier to
    cut). Confidence: moderate for E and the yield strain (ranges of
    ±50 % between sites and donors), low for the cutting energy (calibrated in the docs' "Calibration").
    """

    material: BoneMaterial = Field(default_factory=lambda: BoneMaterial(density_kg_m3=500.0, youngs_modulus_pa=367e6, poisson_ratio=0.2))
    hardening: JohnsonCookHardening = Field(default_factory=lambda: JohnsonCookHardening(a_pa=2.75e6, b_pa=5.6e6))
    damage: JohnsonCookDamage = Field(default_factory=lambda: JohnsonCookDamage(d1=0.5, d2=0.0, d3=0.0))
    specific_cutting_energy_j_m3: float = Field(1e8, ge=1e6, le=1e11, description="u_c of the cutting law in cancellous bone")
    compaction: CrushableFoam | None = Field(CrushableFoam(), description="crushing law; None: von Mises yield, crushing fractures")


#: osteoporotic cancellous bone: apparent density 0.25 g/cm³, the same laws as :class:`CancellousBone`
OSTEOPOROTIC_CANCELLOUS = CancellousBone(
    material=BoneMaterial(density_kg_m3=250.0, youngs_modulus_pa=67e6, poisson_ratio=0.2),
    hardening=JohnsonCookHardening(a_pa=0.5e6, b_pa=1.0e6),
    damage=JohnsonCookDamage(d1=0.5, d2=0.0, d3=0.0),
    specific_cutting_energy_j_m3=3e7,
)
#: cancellous bone by the name the command line and case files use
CANCELLOUS_PRESETS = {"normal": CancellousBone(), "osteoporotic": OSTEOPOROTIC_CANCELLOUS}


class ReamerConfig(_Frozen):
    """Rigid hemispherical reamer head [5.1.2, 5.2.2, 5.3]; any size, its teeth by :func:`teeth_for_diameter` unless given."""

    head_diameter_mm: float = Field(REFERENCE_REAMER_DIAMETER_MM, ge=30.0, le=80.0, description="reamer size (head diameter)")
    tooth_count: int = Field(
        REFERENCE_TOOTH_COUNT, ge=1, le=1000, description="teeth on the head; default: by the size (teeth_for_diameter)"
    )
    tooth_length_mm: float = Field(3.0, gt=0, le=50.0, description="cutting-edge length along the meridian")
    tooth_edge_radius_mm: float = Field(0.25, gt=0, le=10.0, description="radius of the edge's rounded crest")
    tooth_protrusion_mm: float = Field(0.4, gt=0, le=10.0, description="how far the edge stands proud of the head")
    tooth_first_polar_deg: float = Field(3.0, ge=0, lt=90)
    tooth_last_polar_deg: float = Field(86.0, gt=0, le=90)
    omega_rad_s: float = Field(136.0, ge=-1e4, le=1e4, description="spin about the axis D")
    gravity_m_s2: float = Field(9.81, ge=0, le=100.0)
    density_kg_m3: float = Field(7800.0, gt=0, le=1e5, description="AISI 420 steel [Table 9]")
    youngs_modulus_pa: float = Field(200e9, gt=0, le=1e13)
    poisson_ratio: float = Field(0.3, gt=-1.0, lt=0.5)
    wall_thickness_mm: float | None = Field(None, gt=0, description="hollow head's wall; None = the thesis's simplified solid head")

    @model_validator(mode="before")
    @classmethod
    def _teeth_by_size(cls, data):
        if not isinstance(data, dict) or data.get("tooth_count") is not None:
            return data
        try:  # a finite size only: anything else (inf, a list) is the field's to refuse, in one line
            size = float(data.get("head_diameter_mm"))
        except (TypeError, ValueError):
            return data
        return {**data, "tooth_count": teeth_for_diameter(size)} if math.isfinite(size) else data

    @model_validator(mode="after")
    def _tooth_range(self) -> ReamerConfig:
        if self.tooth_first_polar_deg >= self.tooth_last_polar_deg:
            raise ValueError("tooth_first_polar_deg must be below tooth_last_polar_deg")
        if self.wall_thickness_mm is not None and self.wall_thickness_mm >= self.head_diameter_mm / 2:
            raise ValueError("wall_thickness_mm must be below the head radius")
        return self

    @property
    def head_radius(self) -> float:
        return self.head_diameter_mm * 0.5e-3

    @property
    def size_mm(self) -> float:
        """The reamer's size as surgeons name it: the diameter its teeth cut (head plus the teeth standing proud)."""
        return self.head_diameter_mm + 2.0 * self.tooth_protrusion_mm


def head_diameter_for_size(size_mm: float, tooth_protrusion_mm: float | None = None) -> float:
    """Head diameter of the reamer that cuts ``size_mm`` (the teeth stand ``tooth_protrusion_mm`` proud)."""
    protrusion = ReamerConfig.model_fields["tooth_protrusion_mm"].default if tooth_protrusion_mm is None else tooth_protrusion_mm
    return size_mm - 2.0 * protrusion


class ContactConfig(_Frozen):
    """Penalty contact between reamer and bone [5.3.1], its stiffness scaled to the explicit step.

    Node i's penalty stiffness is k_i = β·m_i/Δt² (m_i its lumped, mass-scaled mass), so a node
    on its contact spring has ω·Δt = √β on any mesh and time step. β = 0.8 is a fifth of the
    single-spring stability bound (4); the node's element stiffness and the dampers use the
    rest of the margin (see :func:`contact_stability_terms`). Removal still depends a little on
    β, less the stiffer the contact: on the default case over 30 frames halving β from 0.8
    removed 8.1 % less bone, from 0.4 13.0 % less, so 0.8 (solver 0.4.0; 0.4 before) keeps the
    convergence study within its 10 %.

    ``specific_cutting_energy_j_m3`` (u_c): the teeth cut the volume their friction work pays
    for, W/u_c (:mod:`thrsim.physics.contact`). 0.5 J/mm³ makes the default case (0.45 mm mesh,
    γ 15°, θ 30°, 230 N) seat, feed at 1.3 mm/s and break through at frame 93 of 120; published
    orthogonal cutting of cortical bone is of the order of 0.1 to a few J/mm³.
    """

    friction: float = Field(0.3, ge=0, le=10.0)
    damping_ratio: float = Field(0.2, ge=0, lt=1, description="contact damping as a fraction of critical")
    penalty_factor: float = Field(0.8, gt=0, le=4.0, description="β in k_i = β·m_i/Δt² (node on its contact spring: ω·Δt = √β)")
    specific_cutting_energy_j_m3: float = Field(
        5e8, ge=1e6, le=1e11, description="u_c: volume the teeth cut = their friction work / u_c (thrsim.physics.contact)",
    )  # fmt: skip


#: the contact-friction cap as a fraction of the one-step stick force (thrsim.physics.contact)
STICK_FRACTION = 0.5
#: share of the central-difference bound (ω·Δt)² < 4 kept in reserve for bulk viscosity
STABILITY_RESERVE = 0.1


def contact_stability_terms(safety_factor: float, penalty_factor: float, damping_ratio: float) -> tuple[float, float]:
    """(ω·Δt)²-like sums of a contact node along the normal and along the surface; each must stay
    below 4·(1 − reserve) for the explicit step to stay stable.

    The node's elements run at ω_e·Δt = 2s; the contact spring adds β; a damper applied with the
    previous half-step's velocity, c·Δt/m = a, costs 2a of the bound (central difference with
    lagged damping is stable for (ω·Δt)² + 2a < 4).
    """
    elements = (2.0 * safety_factor) ** 2
    normal = elements + penalty_factor + 2.0 * (2.0 * damping_ratio * math.sqrt(penalty_factor))
    tangential = elements + 2.0 * STICK_FRACTION
    return normal, tangential


class ReamerHoldConfig(_Frozen):
    """The hand-held reamer's axial degree of freedom: what the surgeon's push drives.

    The head (0.186 kg) does not move alone: the shaft, the power driver and the part of the
    surgeon's arm that moves with them (together 1.5–3 kg) move with it, and the arm resists
    fast motion. The push therefore acts on an effective mass with an axial damper to ground:
    M·s̈ = F + G − F_contact·D − c·ṡ. The damper is sized to remove the tooth-impact chatter a
    free 0.186 kg head shows (bouncing ~14 times a frame, airborne 62 % of the steps); at
    reaming feed rates (≈ 0.2 mm/s while seating) c·ṡ is under 1 N, a negligible share of the
    push.
    """

    effective_mass_kg: float = Field(2.0, ge=0.1, le=100.0, description="head + shaft + driver + the arm's share")
    axial_damping_n_s_m: float = Field(2000.0, gt=0, le=1e5, description="arm and driver damping along D")


class Orientation(_Frozen):
    """Reamer orientation in the bone frame: the axis D = (sin γ cos θ, sin γ sin θ, −cos γ) points from the reamer into the bone (−z at γ = 0)."""

    inclination_deg: float = Field(..., ge=0, le=90)
    anteversion_deg: float = Field(..., ge=0, le=360)

    @property
    def reamer_axis(self) -> tuple[float, float, float]:
        g = math.radians(self.inclination_deg)
        t = math.radians(self.anteversion_deg)
        return (pm.sin(g) * pm.cos(t), pm.sin(g) * pm.sin(t), -pm.cos(g))


def _angles_within(values: tuple[float, ...], highest_deg: float, what: str) -> tuple[float, ...]:
    bad = [v for v in values if not 0 <= v <= highest_deg]
    if bad:
        raise ValueError(f"{what} must lie in [0, {highest_deg:g}] degrees, got {bad}")
    return values


class SocketSweepConfig(_Frozen):
    """The 0.5 dataset (``thrsim dataset --bone socket``): windows of the layered socket, each reamed by
    the next reamer size at a prescribed feed, so every case cuts from its first frames at a known
    local feed and the force it takes is recorded; and pushed windows, where a set pressure over the
    window drives the reamer against the bone, so the reaction it must overcome is recorded (stalls
    included); and pushed whole sockets, the contact a seated reamer meets, which the reaction law of
    a whole socket learns from. The one definition of the plan's axes and held-out values.

    Each set-feed case draws one value of every axis; the train cases from the train values only,
    balanced; each test case holds out one axis at a held-out value (a reamer size, a tilt direction,
    a feed never trained on); validation cases tilt toward the validation direction. Every pushed
    window runs at every pressure, along the socket's axis; the held-out windows are test cases.
    Fixed ``seed``: the same plan every time.
    """

    #: (native socket diameter, prepared cavity diameter or None for the native socket, reamer size), mm
    steps: tuple[tuple[float, float | None, float], ...] = (
        (44.0, None, 46.0), (46.0, None, 48.0), (46.0, 48.0, 50.0), (50.0, None, 52.0), (50.0, 52.0, 54.0),
    )  # fmt: skip
    window_polars_deg: tuple[float, ...] = (0.0, 30.0, 55.0, 80.0)
    window_azimuths_deg: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)
    window_half_angle_deg: float = Field(10.0, gt=0, le=45)
    inclinations_deg: tuple[float, ...] = (0.0, 15.0, 30.0)
    anteversions_deg: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)
    #: where the reamer's axis passes (mm, bone frame): the native centre, medialised, raised
    reamer_centres_mm: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, 0.0), (0.0, 0.0, -2.0), (0.0, 2.0, 0.0))
    feeds_mm_s: tuple[float, ...] = (0.5, 1.0, 2.0)
    cancellous: tuple[str, ...] = ("normal", "osteoporotic")
    test_reamer_sizes_mm: tuple[float, ...] = (50.0,)
    test_anteversions_deg: tuple[float, ...] = (45.0, 135.0)
    test_feeds_mm_s: tuple[float, ...] = (1.5,)
    validation_anteversions_deg: tuple[float, ...] = (315.0,)
    #: pushed windows: (window polar, window azimuth, native socket, reamer size) in degrees and mm
    pushed_windows: tuple[tuple[float, float, float, float], ...] = (
        (0.0, 0.0, 44.0, 46.0), (30.0, 0.0, 46.0, 48.0), (55.0, 90.0, 46.0, 48.0), (80.0, 180.0, 50.0, 52.0), (0.0, 0.0, 50.0, 52.0),
        (30.0, 270.0, 44.0, 46.0),
    )  # fmt: skip
    #: the push over the window's area of the native socket, N/mm² (the cutting threshold is near 0.3)
    push_pressures_n_mm2: tuple[float, ...] = (0.2, 0.35, 0.5, 0.8)
    test_pushed_windows: tuple[tuple[float, float], ...] = ((30.0, 270.0),)
    #: pushed whole sockets, the contact a seated reamer meets (a window is held at its cut sides), one
    #: size up and line to line (the first reamer of a sequence): (native socket, reamer size, inclination γ, anteversion θ, push N, split), each solved at every ``whole_socket_element_sizes_mm``
    whole_sockets: tuple[tuple[float, float, float, float, float, str], ...] = (
        (46.0, 48.0, 0.0, 0.0, 230.0, "train"), (46.0, 48.0, 15.0, 30.0, 230.0, "test"),
        (46.0, 48.0, 0.0, 0.0, 310.0, "train"), (46.0, 48.0, 15.0, 180.0, 150.0, "train"),
        (50.0, 52.0, 0.0, 0.0, 230.0, "train"), (44.0, 46.0, 30.0, 90.0, 270.0, "train"),
        (48.0, 50.0, 15.0, 300.0, 200.0, "test"),
        (46.0, 46.0, 0.0, 0.0, 230.0, "train"), (52.0, 52.0, 15.0, 180.0, 270.0, "train"),
        (44.0, 44.0, 30.0, 270.0, 180.0, "train"), (48.0, 48.0, 15.0, 135.0, 230.0, "test"),
    )  # fmt: skip
    #: pushed whole sockets from a cavity prepared by the last reamer (a sequence's next step, cancellous bone
    #: exposed): (native socket, prepared cavity, reamer size, γ, θ, push N, split), meshed like ``whole_sockets``
    prepared_whole_sockets: tuple[tuple[float, float, float, float, float, float, str], ...] = (
        (44.0, 46.0, 48.0, 0.0, 0.0, 230.0, "train"), (50.0, 52.0, 54.0, 15.0, 90.0, 230.0, "train"),
        (44.0, 46.0, 48.0, 15.0, 180.0, 270.0, "train"), (46.0, 48.0, 50.0, 15.0, 30.0, 230.0, "test"),
        (48.0, 50.0, 52.0, 0.0, 0.0, 230.0, "train"), (50.0, 52.0, 54.0, 0.0, 0.0, 230.0, "train"),
        (48.0, 50.0, 52.0, 15.0, 180.0, 270.0, "train"), (48.0, 50.0, 52.0, 15.0, 90.0, 230.0, "train"),
        (50.0, 52.0, 54.0, 15.0, 270.0, 200.0, "train"), (44.0, 46.0, 48.0, 15.0, 0.0, 170.0, "train"),
        (46.0, 48.0, 50.0, 0.0, 0.0, 190.0, "train"), (48.0, 50.0, 52.0, 15.0, 270.0, 160.0, "train"),
        (50.0, 52.0, 54.0, 15.0, 180.0, 180.0, "train"),
    )  # fmt: skip
    #: the element sizes (mm) every whole socket is meshed at: the trainer's 1.5 mm, then the finer 1.0 mm
    whole_socket_element_sizes_mm: tuple[float, ...] = (1.5, 1.0)
    #: long pushed whole sockets, a reamer held seated for seconds (the trainer's steps last that long):
    #: (native socket, prepared cavity or None, reamer size, γ, θ, push N, split), run for
    #: ``long_whole_socket_frames`` at the first of ``whole_socket_element_sizes_mm``
    long_whole_sockets: tuple[tuple[float, float | None, float, float, float, float, str], ...] = (
        (46.0, None, 48.0, 0.0, 0.0, 230.0, "train"), (46.0, None, 46.0, 0.0, 0.0, 230.0, "train"),
        (46.0, None, 48.0, 15.0, 30.0, 230.0, "test"), (44.0, None, 46.0, 30.0, 90.0, 270.0, "train"),
        (46.0, None, 48.0, 30.0, 0.0, 230.0, "train"), (46.0, 48.0, 50.0, 15.0, 90.0, 230.0, "train"),
        (46.0, None, 48.0, 15.0, 180.0, 270.0, "train"), (50.0, None, 52.0, 15.0, 270.0, 200.0, "train"),
    )  # fmt: skip
    long_whole_socket_frames: FrameCount = 240
    train_cases: int = Field(36, ge=0, le=10_000, description="set-feed cases to train on (0: the pushed windows only)")
    validation_cases: int = Field(6, ge=0, le=10_000)
    test_cases: int = Field(9, ge=0, le=10_000)
    frames: FrameCount = 60
    seed: int = 0

    @field_validator("whole_sockets", "prepared_whole_sockets", "long_whole_sockets")
    @classmethod
    def _known_split(cls, values: tuple) -> tuple:
        unknown = sorted({v[-1] for v in values} - {"train", "validation", "test"})
        if unknown:
            raise ValueError(f"unknown split(s) {unknown} of a whole socket: train, validation or test")
        return values

    @field_validator("whole_socket_element_sizes_mm")
    @classmethod
    def _element_sizes(cls, values: tuple[float, ...]) -> tuple[float, ...]:
        if not values or len(set(values)) != len(values) or not all(0.3 <= v <= 3.0 for v in values):
            raise ValueError(f"one or more distinct element sizes in [0.3, 3] mm, got {list(values)}")
        return values

    @field_validator("cancellous")
    @classmethod
    def _known_cancellous(cls, values: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [v for v in values if v not in CANCELLOUS_PRESETS]
        if unknown:
            raise ValueError(f"unknown cancellous preset(s) {unknown}: known {sorted(CANCELLOUS_PRESETS)}")
        return values


class SweepConfig(_Frozen):
    """Orientation sweep of the training cases [5.3.4]: the one definition of the sweep's
    defaults (``thrsim.data.sweep`` and ``thrsim dataset``'s options take theirs from here).

    The full orientation grid runs at ``forces_n``; ``extra_forces_n`` run on the grid's
    orientations whose anteversion is in ``extra_force_anteversions_deg`` (every inclination).
    """

    inclinations_deg: tuple[float, ...] = (0.0, 15.0, 30.0, 45.0)
    anteversions_deg: tuple[float, ...] = tuple(float(a) for a in range(0, 181, 15))
    forces_n: tuple[float, ...] = Field((PUSH_FORCE_N,), description="the thesis's mean push force [5.3.2]")
    extra_forces_n: tuple[float, ...] = (150.0, 310.0)
    extra_force_anteversions_deg: tuple[float, ...] = (0.0, 90.0, 180.0)
    frames: FrameCount = 120
    frame_rate_hz: FrameRateHz = FRAME_RATE_HZ

    @field_validator("inclinations_deg")
    @classmethod
    def _inclinations_in_range(cls, values: tuple[float, ...]) -> tuple[float, ...]:
        return _angles_within(values, 90.0, "inclinations")

    @field_validator("anteversions_deg")
    @classmethod
    def _anteversions_in_range(cls, values: tuple[float, ...]) -> tuple[float, ...]:
        return _angles_within(values, 360.0, "anteversions")

    @property
    def frame_dt_s(self) -> float:
        return 1.0 / self.frame_rate_hz


class LabelConfig(_Frozen):
    """Element label α [7.2.1, eq. 47]: α = 1 − (PEEQ + τ·max(0, 1 − μ·σ_M/σ_scale)), clipped."""

    mu: float = 0.38
    tau: float = 0.42
    von_mises_scale_pa: float = Field(1e7, gt=0)
    removed_threshold: float = Field(0.3, gt=0, lt=1)
    crushed_bone_is_lost: bool = Field(
        False,
        description="read a crushable foam's plastic strain (compaction) as material lost, as eq. 47 reads every element's; "
        "False: its damage takes that place (crushed bone stays, denser)",
    )


class SafeZone(_Frozen):
    """Lewinnek safe zone (radiographic angles)."""

    inclination_deg: float = Field(40.0, ge=0, le=90)
    inclination_tolerance_deg: float = Field(10.0, gt=0)
    anteversion_deg: float = Field(15.0, ge=-90, le=90)
    anteversion_tolerance_deg: float = Field(10.0, gt=0)
    warning_margin_deg: float = Field(5.0, ge=0, description="outside the zone by at most this: amber, beyond: red")


class TrackingVolumeConfig(_Frozen):
    """Optical camera volume like an NDI Polaris Vega: truncated pyramid along the view axis."""

    near_mm: float = Field(950.0, gt=0)
    far_mm: float = Field(2400.0, gt=0)
    near_half_width_mm: float = Field(224.0, gt=0)
    near_half_height_mm: float = Field(240.0, gt=0)
    far_half_width_mm: float = Field(656.0, gt=0)
    far_half_height_mm: float = Field(783.0, gt=0)
    max_marker_angle_deg: float = Field(45.0, gt=0, le=90)
    noise_rms_mm: float = Field(0.25, ge=0)
    rate_hz: float = Field(60.0, gt=0)
    landmark_count: int = Field(27, ge=3)
    landmark_tolerance_mm: float = Field(5.0, gt=0, description="probe tip to target distance that counts as on it")
    dwell_s: float = Field(0.5, gt=0, description="how long the probe is held still on a target to acquire it")
    still_tolerance_mm: float = Field(3.0, gt=0, description="tip wander during the dwell that still counts as still")

    @model_validator(mode="after")
    def _depths(self) -> TrackingVolumeConfig:
        if self.near_mm >= self.far_mm:
            raise ValueError("near_mm must be below far_mm")
        return self


LOOPBACK_NETWORKS = ("127.0.0.0/8", "::1/128")
#: OpenIGTLink's registered TCP port (IANA), where the listener and PlusServer's configurations listen by default
OPENIGTLINK_PORT = 18944
#: the haptic stream's rate (``thrsim serve --haptic-port``): twice a 1 kHz haptic loop's, so the
#: newest force a loop reads is never more than half its period old (HIPS-style loops answer in under 1 ms)
HAPTIC_RATE_HZ = 2000.0
KNOWN_TRACKER_DEVICES = ("ReamerToReference", "ReamerToTracker", "ReferenceToTracker", "ProbeToReference", "ProbeToTracker")


class IgtlConfig(_Frozen):
    """OpenIGTLink listener: where it listens, whom it admits and how much it tolerates from a peer.

    Only peers in ``allowed_peers`` (networks; loopback alone by default) are served; a connection
    from anywhere else is closed at once. Poses are kept per device name: the ``known_devices``
    always, and at most ``max_other_devices`` other names (first come), so no client can grow the
    shared tracker state without bound by inventing names. A connection that sends nothing for
    ``idle_timeout_s`` is closed, unless, with ``feedback``, it reads what the trainer sends it. A client earns its slot by sending what the trainer uses (a
    known device's pose, a force): when every one of the ``max_clients`` slots is taken, a
    newcomer takes the slot of a connection that has earned nothing in the ``reclaim_after_s``
    since it connected, else of the one whose last useful message is oldest and older than
    ``idle_timeout_s``; otherwise the newcomer is refused (see :mod:`thrsim.io.server`).
    """

    host: str = "127.0.0.1"
    port: int = Field(OPENIGTLINK_PORT, ge=0, le=65535, description="0 = any free port (tests)")
    max_body_bytes: int = Field(1 << 20, gt=0)
    max_clients: int = Field(32, ge=1)
    io_timeout_s: float = Field(5.0, gt=0, description="a started message or a reply must finish within this")
    idle_timeout_s: float = Field(
        15.0, gt=0, description="a connection that sends no message for this long is closed; none useful, it gives way when wanted"
    )
    reclaim_after_s: float = Field(
        1.0, ge=0, description="when all slots are taken, a connection that sent nothing useful this long since connecting gives way"
    )
    stale_pose_s: float = Field(0.5, gt=0, description="a pose older than this no longer counts as tracked")
    known_devices: tuple[str, ...] = Field(KNOWN_TRACKER_DEVICES, description="TRANSFORM device names always accepted")
    max_other_devices: int = Field(8, ge=0, description="further TRANSFORM device names accepted, first come")
    allowed_peers: tuple[IPvAnyNetwork, ...] = Field(
        LOOPBACK_NETWORKS, validate_default=True, description="networks whose peers are served"
    )
    feedback: bool = Field(
        False, description="send every peer the trainer's events and simulated reamer (thrsim.io.feedback); one that reads them is not idle"
    )

    @field_validator("known_devices")
    @classmethod
    def _device_names_fit_the_header(cls, names: tuple[str, ...]) -> tuple[str, ...]:
        for name in names:
            if not name or not name.isprintable() or not name.isascii() or len(name) > 20:
                raise ValueError(f"device name {name!r} must be 1 to 20 printable ASCII characters")
        return names


class SessionEndLimit(_Frozen):
    """How often the trainer's viewers may end sessions, all modes together: each end writes a session
    file and starts a fresh session, so a page repeating ``end_session`` must not fill the disk. A
    token bucket: ``burst`` ends at once, then one more every ``refill_s``."""

    burst: int = Field(5, ge=1)
    refill_s: float = Field(10.0, gt=0, description="one more end allowed this often")


class LiveSessionLimit(_Frozen):
    """How many sessions the trainer runs at once, all modes together: every page that opens gets
    its own (its trainee's), and a reaming session steps its simulator every tick."""

    sessions: int = Field(8, ge=1)


class SolverConfig(_Frozen):
    """Explicit central-difference settings of the ground-truth solver."""

    target_dt_s: float = Field(4e-6, ge=1e-8, le=1e-3, description="time step reached by per-element mass scaling")
    safety_factor: float = Field(
        0.7, gt=0, le=1,
        description="fraction of the Courant limit the mass-scaled elements run at; 0.7 leaves the margin contact needs",
    )  # fmt: skip
    max_kinetic_to_internal: float = Field(0.1, gt=0, le=100.0, description="reported target after first contact")
    energy_blowup_factor: float = Field(
        10.0,
        gt=1,
        le=1e12,
        description="stop when the bone's kinetic energy exceeds this × the work done (it can never legitimately exceed 1 ×)",
    )
    threads: int | None = Field(None, ge=1, le=4096, description="Numba threads; None = all cores")
    active_zone: Literal["auto", "on", "off"] = Field(
        "auto", description="integrate only the elements the reamer can reach soon (auto: on for the socket, off for the patch)"
    )
    zone_halo_mm: float = Field(1.5, gt=0, le=50.0, description="bone integrated beyond the teeth's reach, held beyond it")
    zone_lookahead_mm: float = Field(
        0.5, ge=0, le=50.0, description="how far ahead along D the zone reaches, besides the reamer's own travel"
    )
    zone_steps: int = Field(400, ge=1, le=1_000_000, description="steps between two choices of the zone")


class ReamingCaseConfig(_Frozen):
    """One ground-truth reaming case: an orientation, a push force, a number of frames, all settings."""

    inclination_deg: float = Field(..., ge=0, le=90)
    anteversion_deg: float = Field(..., ge=0, le=360)
    force_n: float = Field(PUSH_FORCE_N, ge=0, le=10_000.0, description="surgeon's axial push along D; the thesis's mean 230 N [5.3.2]")
    feed_mm_s: float | None = Field(
        None, gt=0, le=100, description="feed control: the reamer advances at this rate and the push is what it takes (None: force control)"
    )
    frames: FrameCount = 120
    frame_rate_hz: FrameRateHz = FRAME_RATE_HZ
    bone_kind: Literal["patch", "socket"] = Field("patch", description="the thesis's patch, or the layered socket")
    pre_ream_mm: float | None = Field(
        None, gt=0, description="the socket starts reamed geometrically to this diameter (a previous reamer's cavity); None: native"
    )
    pre_ream_centre_mm: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="the prepared cavity's centre in the bone frame")
    reamer_centre_mm: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0),
        description="the point of the bone frame the reamer's axis passes through: its centre moves along D through it "
        "(the origin, the native socket's centre; offset it to medialise or raise the cavity)",
    )
    start_from: str | None = Field(
        None, description="a case file whose last frame this case starts from (its removed bone, damage and PEEQ; same mesh and solver)"
    )
    bone: BonePatchConfig = BonePatchConfig()
    socket: SocketConfig = SocketConfig()
    cancellous: CancellousBone = CancellousBone()
    material: BoneMaterial = BoneMaterial()
    hardening: JohnsonCookHardening = JohnsonCookHardening()
    damage: JohnsonCookDamage = JohnsonCookDamage()
    reamer: ReamerConfig = ReamerConfig()
    contact: ContactConfig = ContactConfig()
    hold: ReamerHoldConfig = ReamerHoldConfig()
    solver: SolverConfig = SolverConfig()

    @model_validator(mode="after")
    def _contact_within_stable_step(self) -> ReamingCaseConfig:
        bound = 4.0 * (1.0 - STABILITY_RESERVE)
        normal, tangential = contact_stability_terms(self.solver.safety_factor, self.contact.penalty_factor, self.contact.damping_ratio)
        if max(normal, tangential) >= bound:
            raise ValueError(
                f"contact.penalty_factor {self.contact.penalty_factor:g} with damping_ratio {self.contact.damping_ratio:g} and "
                f"solver.safety_factor {self.solver.safety_factor:g} would break the stable step "
                f"(stability sums {normal:.2f} normal, {tangential:.2f} tangential; each must stay below {bound:.2f})"
            )
        return self

    @model_validator(mode="after")
    def _preparation_fits(self) -> ReamingCaseConfig:
        if self.bone_kind != "socket" and any(self.reamer_centre_mm):
            raise ValueError("reamer_centre_mm applies to the socket (bone_kind socket) only: the patch's reamer aims at its pole")
        if math.dist(self.reamer_centre_mm, (0.0, 0.0, 0.0)) > 0.5 * self.socket.socket_diameter_mm:
            raise ValueError(
                f"reamer_centre_mm {self.reamer_centre_mm} lies outside the native socket (radius {self.socket.socket_radius_mm:g} mm)"
            )
        if self.pre_ream_mm is not None and self.start_from is not None:
            raise ValueError("give pre_ream_mm or start_from, not both: a chained case starts from the previous case's bone")
        if self.pre_ream_mm is None:
            return self
        if self.bone_kind != "socket":
            raise ValueError("pre_ream_mm applies to the socket (bone_kind socket) only")
        cutting_mm = self.reamer.size_mm
        if cutting_mm < self.pre_ream_mm:
            raise ValueError(
                f"a {cutting_mm:g} mm reamer is smaller than the {self.pre_ream_mm:g} mm prepared cavity: it cannot cut its wall "
                "(step up 1-2 mm)"
            )
        reach_mm = 0.5 * self.pre_ream_mm + math.dist(self.pre_ream_centre_mm, (0.0, 0.0, 0.0))
        stock_mm = self.socket.fine_radius_mm
        if reach_mm >= stock_mm:
            raise ValueError(
                f"a {self.pre_ream_mm:g} mm pre-ream reaches {reach_mm:g} mm from the socket centre, beyond the bone stock "
                f"meshed for reamers up to {self.socket.planned_reamer_max_diameter_mm:g} mm ({stock_mm:g} mm; raise "
                "socket.planned_reamer_max_mm)"
            )
        return self

    @property
    def orientation(self) -> Orientation:
        return Orientation(inclination_deg=self.inclination_deg, anteversion_deg=self.anteversion_deg)

    @property
    def frame_dt_s(self) -> float:
        return 1.0 / self.frame_rate_hz


def _set_dotted(tree: dict, dotted: str, value) -> None:
    *parents, leaf = dotted.split(".")
    for key in parents:
        tree = tree.setdefault(key, {})
    tree[leaf] = value


def read_settings_file(path: str) -> dict:
    """The JSON object of (partial, nested) settings in ``path``; ThrsimInputError if missing or malformed."""
    import json
    from pathlib import Path

    from thrsim.errors import ThrsimInputError

    file = Path(path)
    if not file.is_file():
        raise ThrsimInputError(f"{file}: no such configuration file")
    try:
        settings = json.loads(file.read_text())
    except (ValueError, UnicodeDecodeError) as error:  # JSONDecodeError, or an integer of thousands of digits
        raise ThrsimInputError(f"{file}: not valid JSON ({error})") from None
    except RecursionError:
        raise ThrsimInputError(f"{file}: not valid JSON (nested too deeply)") from None
    if not isinstance(settings, dict):
        raise ThrsimInputError(f"{file}: the configuration must be a JSON object")
    return settings


def load_case_config(path: str | None, overrides: dict[str, object]) -> ReamingCaseConfig:
    """A reaming case from an optional JSON file of (partial, nested) settings, then dotted overrides.

    ``overrides`` maps dotted field names (``bone.element_size_mm``) to values; None means "not
    given". A missing or malformed file raises :class:`ThrsimInputError`; bad values raise
    pydantic's ``ValidationError``.
    """
    settings = read_settings_file(path) if path is not None else {}
    for dotted, value in overrides.items():
        if value is not None:
            _set_dotted(settings, dotted, value)
    return ReamingCaseConfig.model_validate(settings)
