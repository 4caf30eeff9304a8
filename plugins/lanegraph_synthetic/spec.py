"""What a synthetic scene is (:mod:`.scene` renders it): the rig (:data:`KITTI_CALIB`, pitch, roll,
height), the road (curvature, clothoid rate, lanes, :class:`Marking`), the appearance and the
objects, as a :class:`SceneSpec`; and the named presets (:data:`PRESETS`, :func:`preset`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from lanegraph.types import Calibration

from .objects import Box, Pole

#: the KITTI colour pair's calibration (1242 x 375), the default rig


#: the KITTI colour pair's calibration (1242 x 375), the default rig
KITTI_CALIB = Calibration(f=721.5377, cx=609.5593, cy=172.8540, baseline=0.5327, width=1242, height=375)


@dataclass
class Marking:
    """A longitudinal lane marking.

    ``offset``: lateral position of its centre line in road coordinates (metres, right positive);
    ``kind``: ``"solid"`` or ``"dashed"``; ``width`` metres; a dashed marking has ``dash`` metres of
    paint then ``gap`` metres without, the first dash starting at ``s = phase`` metres.
    """

    offset: float
    kind: str = "solid"
    width: float = 0.15
    dash: float = 3.0
    gap: float = 6.0
    phase: float = 0.0


@dataclass
class SceneSpec:
    """Everything that defines a synthetic sequence. Build one from a preset with :func:`preset`.

    Lengths in metres, angles in degrees, speeds in metres per second, densities per 100 m of road.
    ``markings=None`` paints the standard layout of ``n_lanes`` lanes (outer lines ``outer_kind``,
    inner ``inner_kind``); an explicit list replaces it (``[]``: no markings at all).
    """

    preset: str = "straight"
    calib: Calibration = KITTI_CALIB
    pitch_deg: float = 1.0
    roll_deg: float = 0.0
    height: float = 1.65
    # --- road layout
    n_lanes: int = 3
    ego_lane: int = -1  # lane index from the left; -1: n_lanes // 2
    lane_width: float = 3.6
    marking_width: float = 0.15
    inner_kind: str = "dashed"
    outer_kind: str = "solid"
    dash_length: float = 3.0
    gap_length: float = 6.0
    shoulder: float = 0.6  # paved road beyond the outer markings
    markings: list[Marking] | None = None
    curvature: float = 0.0  # 1/m at s = 0, positive bends right
    curvature_rate: float = 0.0  # 1/m**2, the curvature's change per metre travelled (clothoid)
    # --- ego motion
    speed: float = 10.0
    fps: float = 10.0
    lateral_speed: float = 0.0  # drift to the right
    lane_change: int = 0  # -1 left, +1 right, 0 none
    lane_change_start: float = 0.5  # seconds
    lane_change_duration: float = 3.0  # seconds
    # --- appearance
    noise_sigma: float = 2.0  # grey levels
    texture_contrast: float = 12.0  # grey levels
    verge_texture: float = 1.0  # the verge's texture contrast relative to the asphalt's (grass, gravel: 2-4)
    blur_sigma: float = 0.5  # optics, pixels
    right_gain: float = 1.0  # the right camera's exposure relative to the left
    shadow_strength: float = 0.55
    shadows: float = 0.0  # soft canopy shadows on the road (trees out of view)
    trees: float = 0.0  # tree trunks beside the road with canopy shadows
    poles: float = 0.0
    parked_cars: float = 0.0
    traffic: int = 0  # moving cars ahead (a number, not a density)
    walls: bool = False
    kerb_height: float = 0.0  # > 0: a concrete kerb this high (metres) along both road edges
    # side roads joining on the right, unpainted: where each one's near corner starts (metres along
    # a tile); its kerbs (kerb_height, which must be > 0) leave the main road's right edge in a
    # quarter circle of side_road_radius metres, the side road side_road_width metres wide between
    # its corners
    side_roads: tuple[float, ...] = ()
    side_roads_left: tuple[float, ...] = ()  # the same on the left
    side_road_width: float = 6.0
    side_road_radius: float = 12.0
    arrows: float = 0.0
    hatching: float = 0.0
    # a ramp's gore area: > 0 paints a second solid line this far left of the leftmost marking and
    # hatches the area between them (bars 0.45 m wide every gore_step metres along the road)
    gore_width: float = 0.0
    gore_pattern: str = "chevron"  # "chevron" (V-shaped bars) or "stripes" (parallel diagonal bars)
    gore_step: float = 2.0
    # dappled tree shade: the road under a canopy in shade (shadow_strength), with hard-edged sun
    # patches covering this fraction of it (0: no canopy)
    dappled: float = 0.0
    # worn paint: the fraction of the paint's contrast worn away, the fraction of each marking's
    # length worn through (gaps of 0.2-1.5 m), and strips of darker repair asphalt (per 100 m of
    # road, 1-3 m long, across the road, without paint)
    paint_wear: float = 0.0
    paint_gaps: float = 0.0
    repair_strips: float = 0.0
    objects: list[Box | Pole] = field(default_factory=list)  # extra objects, road coordinates
    # --- exposure
    overexposed_frames: tuple[int, ...] = ()
    overexposed_every: int = 0  # every n-th frame (k % n == 0) is over-exposed; 0: none
    exposure_gain: float = 2.2
    # --- extents
    z_far: float = 200.0  # the road ends here (sky beyond)
    gt_max_distance: float = 50.0  # lane ground truth up to this distance ahead
    tile_length: float = 300.0  # shadows, paint and objects repeat with this period
    seed: int = 0

    def __post_init__(self) -> None:
        if not 1 <= self.n_lanes <= 6:
            raise ValueError(f"SceneSpec.n_lanes: expected 1..6, got {self.n_lanes}")
        if self.ego_lane >= self.n_lanes:
            raise ValueError(f"SceneSpec.ego_lane: expected < n_lanes={self.n_lanes}, got {self.ego_lane}")
        for name in ("inner_kind", "outer_kind"):
            if getattr(self, name) not in ("solid", "dashed"):
                raise ValueError(
                    f"SceneSpec.{name}: expected 'solid' or 'dashed', got {getattr(self, name)!r}"
                )
        if not self.verge_texture >= 0:
            raise ValueError(
                f"SceneSpec.verge_texture: expected >= 0 (relative to the asphalt's texture), got {self.verge_texture}"
            )
        if self.height <= 0 or self.fps <= 0 or self.z_far <= 5:
            raise ValueError("SceneSpec: height, fps must be > 0 and z_far > 5 m")
        if self.tile_length < self.z_far + 80:
            raise ValueError(f"SceneSpec.tile_length: expected >= z_far + 80 m, got {self.tile_length}")
        if self.gore_pattern not in ("chevron", "stripes"):
            raise ValueError(
                f"SceneSpec.gore_pattern: expected 'chevron' or 'stripes', got {self.gore_pattern!r}"
            )
        for name in ("dappled", "paint_wear", "paint_gaps"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise ValueError(
                    f"SceneSpec.{name}: expected a fraction in [0, 1), got {getattr(self, name)}"
                )
        if self.gore_width < 0 or self.gore_step <= 0 or self.repair_strips < 0:
            raise ValueError("SceneSpec: gore_width and repair_strips must be >= 0, gore_step > 0")
        if self.side_roads or self.side_roads_left:
            span = 2 * self.side_road_radius + self.side_road_width
            if self.kerb_height <= 0 or self.side_road_radius <= 0 or self.side_road_width <= 0:
                raise ValueError(
                    "SceneSpec.side_roads: expected kerb_height, side_road_radius and side_road_width > 0"
                )
            if any(not 0 <= s <= self.tile_length - span for s in self.side_roads + self.side_roads_left):
                raise ValueError(
                    f"SceneSpec.side_roads: expected positions in [0, {self.tile_length - span:g}] m "
                    f"(a side road spans {span:g} m of a {self.tile_length:g} m tile), got "
                    f"{self.side_roads} (right), {self.side_roads_left} (left)"
                )
        if self.calib.width <= 0 or self.calib.height <= 0:
            raise ValueError("SceneSpec.calib: width and height (pixels) must be set")

    @property
    def pitch(self) -> float:
        """Pitch, radians."""
        return math.radians(self.pitch_deg)

    @property
    def roll(self) -> float:
        """Roll, radians."""
        return math.radians(self.roll_deg)

    def is_overexposed(self, k: int) -> bool:
        return k in self.overexposed_frames or (
            self.overexposed_every > 0 and k % self.overexposed_every == 0
        )


#: named starting points; every field may be overridden (see :func:`preset`)
PRESETS: dict[str, dict] = {
    "straight": {},
    "curved": {"curvature": 1.0 / 350.0},
    "clothoid": {"curvature": -0.002, "curvature_rate": 8e-5},
    "urban": {
        "n_lanes": 2,
        "lane_width": 3.3,
        "shoulder": 2.6,
        "speed": 8.0,
        "pitch_deg": 0.6,
        "roll_deg": 0.3,
        "shadows": 8.0,
        "trees": 6.0,
        "poles": 4.0,
        "parked_cars": 10.0,
        "traffic": 1,
        "walls": True,
        "arrows": 3.0,
        "hatching": 1.0,
        "noise_sigma": 2.5,
        "right_gain": 0.97,
    },
    "no_markings": {
        "markings": [],
        "shoulder": 1.0,
        "shadows": 6.0,
        "trees": 3.0,
        "poles": 2.0,
        "parked_cars": 4.0,
    },
    "overexposed": {"overexposed_every": 2, "exposure_gain": 2.2},
    # what makes real streets hard for the paper's literal rules: kerbs beside the outer lines,
    # arrows and hatching between them, parked cars and shadows
    "kerbs": {
        "n_lanes": 2,
        "lane_width": 3.4,
        "shoulder": 0.5,
        "kerb_height": 0.13,
        "arrows": 8.0,
        "hatching": 3.0,
        "shadows": 8.0,
        "parked_cars": 6.0,
        "poles": 3.0,
        "curvature": 1.0 / 500.0,
    },
    # a residential street without paint: kerbs on both sides, side roads joining on the right, their
    # kerbs curving away from the road's edge (what a lane finder must not take for a line)
    "residential": {
        "n_lanes": 2,
        "lane_width": 3.2,
        "shoulder": 0.4,
        "markings": [],
        "kerb_height": 0.12,
        "side_roads": (12.0, 90.0, 190.0),
        "shadows": 4.0,
        "trees": 3.0,
        "parked_cars": 2.0,
        "speed": 6.0,
    },
}


def preset(name: str = "straight", **overrides) -> SceneSpec:
    """The :class:`SceneSpec` of preset ``name`` (one of :data:`PRESETS`) with ``overrides`` applied."""
    if name not in PRESETS:
        raise ValueError(f"unknown synthetic scene preset {name!r}; known: {', '.join(PRESETS)}")
    return replace(SceneSpec(preset=name), **{**PRESETS[name], **overrides})
