"""Agent settings: which variant runs, how it looks around, reaches, places and gives up.

The method's own hyper-parameters (thresholds, alpha_d, IG assumption, map layers) live in
:class:`helios.config.HeliosConfig`; this tree holds what the paper leaves to the robot: Spot's
reach and camera placement, the view pattern, the place skill, and the search's bookkeeping.
Every variant of the paper's ablation table is the same code with different values here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from helios.planning.fmm import PlannerConfig
from helios.search.gaze_points import GazeConfig
from helios.schema import require, require_range


@dataclass(frozen=True)
class ViewConfig:
    """How the agent looks with Spot's hand camera (60 degrees wide at 320 x 240)."""

    look_yaws_deg: tuple[float, ...] = (-60.0, 0.0, 60.0)
    """Gaze directions relative to the body heading after each move: three 60-degree views cover
    the half plane in front."""
    start_look_yaws_deg: tuple[float, ...] = (-100.0, -50.0, 0.0, 50.0, 100.0)
    """Gaze directions of the first look (260 degrees without turning the body, which might
    sweep into something the robot has not seen yet)."""
    start_turn_around: bool = True
    """After the first look, turn round in place and look again (360 degrees before moving)."""
    start_near_yaws_deg: tuple[float, ...] = (-60.0, 0.0, 60.0)
    """Near-floor views of the first look (and of a look-around when stuck): the robot starts
    surrounded by floor it has never seen and may only walk where it has looked."""
    look_distance: float = 2.5
    """Gaze points lie this far (m) ahead in each direction ..."""
    look_height: float = 0.3
    """... at this height (m): the view spans the floor from ~1.2 m out up to table and counter tops."""
    near_look_distance: float = 1.2
    """Each look ends with a view of the floor this far (m) ahead: the far views start seeing the
    floor ~1.5 m out, and the body may only walk where the camera has looked. 0 disables it."""
    shoulder_ahead: float = 0.29
    elbow_radius: float = 0.42
    """Looking needs no tall obstacle within this (m) of the shoulder: moving the arm swings its
    links up to 0.34 m round the shoulder on any side (measured in sim), plus their thickness."""
    arm_swing_radius: float = 0.55
    """... nor on the arc the hand sweeps towards the look direction, out to this (m) from the
    shoulder (link frames 0.34 m plus the gripper)."""
    arm_swing_height: float = 0.76
    """Obstacles taller than this (m) count for the radius model's arm checks (tables, <= 0.74 m,
    pass; counters, shelves and walls do not). The measured model keeps its own heights per look
    pitch: steep looks at the floor take the gripper down to 0.63 m."""
    arm_model: Literal["radius", "measured"] = "measured"
    """How the agent predicts where the arm goes when it looks (:mod:`helios.agents.arm_room`).
    ``measured`` (default since 2026-12-05): the simulated arm's swept envelope per band of the
    look's pitch, a strip ahead of the body, lower for steep looks at the floor, higher for looks
    at counter tops (``python -m tools arm-envelope`` measures it). ``radius`` (the earlier model):
    ``elbow_radius`` round the shoulder on any side and ``arm_swing_radius`` towards the look, for
    obstacles over ``arm_swing_height``; it refused looks at objects on counters and cabinets from
    their gaze points and let the arm hit walls and tables (16 gaze collisions in 100 train
    episodes against none; docs/search-experiments.md, "The arm's room, measured")."""
    make_room_distance: float = 0.5
    """When a wall is too close to look around, the robot steps up to this far (m) away first."""
    self_mask_margin: float = 0.08
    """Depth points within the body footprint box grown by this (m) are the robot itself ..."""
    self_mask_top: float = 0.25
    """... if they lie below this height above the body origin (m); the arm is never masked."""
    face_tolerance: float = 1.05
    """Before a grasp or place gaze, turn the body towards the point if it lies more than this
    (rad, 60 degrees) to the side; the gaze itself reaches about 105 degrees."""
    camera_in_body: tuple[float, float, float] = (0.41, 0.02, 0.55)
    """Hand camera position (m, body frame) while gazing, measured in sim; used to predict the
    camera pose of hypothetical views (information gain, predicted scores)."""

    def __post_init__(self) -> None:
        require(bool(self.look_yaws_deg) and bool(self.start_look_yaws_deg), "look yaw lists must not be empty")
        require(self.look_distance > 0.3, "look_distance must be > 0.3 m")
        for name in ("look_yaws_deg", "start_look_yaws_deg", "start_near_yaws_deg"):
            require(all(-360.0 <= v <= 360.0 for v in getattr(self, name)),
                    f"{name} must be angles within [-360, 360] degrees")
        require_range(self, "look_distance", 0.3, 20.0, lo_open=True)
        require_range(self, "look_height arm_swing_height self_mask_top", 0.0, 3.0)
        require_range(self, "near_look_distance", 0.0, 10.0)
        require_range(self, "shoulder_ahead elbow_radius arm_swing_radius make_room_distance self_mask_margin",
                      0.0, 3.0)
        require_range(self, "face_tolerance", 0.0, 3.1416)
        require(self.arm_model in ("radius", "measured"), f"arm_model must be 'radius' or 'measured', got {self.arm_model!r}")
        require(all(abs(v) <= 2.0 for v in self.camera_in_body), "camera_in_body must lie within 2 m of the body")


@dataclass(frozen=True)
class ReachConfig:
    """Where Spot can stand to grasp or place at a point (numbers from robots/spot/model.py)."""

    shoulder_height: float = 0.72
    """Arm shoulder height above the floor at the stand pose (m)."""
    shoulder_ahead: float = 0.29
    """Shoulder ahead of the body centre (m)."""
    arm_reach: float = 0.82
    """Shoulder-to-point distance the arm handles comfortably (m)."""
    min_standoff: float = 0.55
    """Closest body-centre-to-point distance considered (m)."""
    band: float = 0.35
    """Standing distances from ``far - band`` to ``far`` are tried (m)."""
    grasp_lift: float = 0.15
    """Aim point for choosing a grasp pose lies this far above the object centre (room to lift)."""
    place_lift: float = 0.25
    """The hand holds the object about this far above the surface when it lets go (m)."""
    n_angles: int = 24
    close_in_threshold: float = 0.1
    """Before a grasp, step towards the object if it lies this much beyond the comfortable
    standing distance (m)."""
    close_in_radius: float = 0.08
    """Goal radius of that step (m)."""

    def __post_init__(self) -> None:
        require(self.arm_reach > 0 and self.band >= 0 and self.n_angles >= 4, "invalid reach settings")
        require_range(self, "shoulder_height shoulder_ahead min_standoff band grasp_lift place_lift "
                            "close_in_threshold", 0.0, 3.0)
        require_range(self, "arm_reach close_in_radius", 0.0, 3.0, lo_open=True)
        require_range(self, "n_angles", 4, 3600)


@dataclass(frozen=True)
class PlaceConfig:
    """The place skill: the paper's drop, or the improved variant (behind ``mode``)."""

    mode: Literal["drop", "improved"] = "drop"
    """``drop``: release ``drop_height`` above the highest detected point in the region in front
    (the paper's heuristic); ``improved``: lower the object to ``improved_height`` above the middle
    of the detected top surface, away from its edges."""
    drop_height: float = 0.10
    improved_height: float = 0.02
    """Each mode reads its own height only (no order between them is required: one required
    ``improved_height <= drop_height`` even in drop mode, so raising the improved height meant
    raising a height that mode never reads)."""
    region: tuple[float, float, float, float] = (0.45, 1.05, -0.35, 0.35)
    """Body-frame box (x0, x1, y0, y1, m) in front of the robot searched for the release point."""
    top_band: float = 0.03
    """Points within this (m) of the highest one form the top surface (improved mode)."""
    surface_cell: float = 0.02
    """Grid (m) on which the top surface is rasterised to find its most interior point."""
    mask_erosion_px: int = 2
    """The receptacle's detection mask is eroded by this many pixels first: its boundary pixels
    mix in the wall or floor behind (detector masks are noisy), whose "highest point" is no place."""
    approach_inset: float = 0.20
    """The approach aims at the receptacle's nearest footprint point moved this far (m) inwards."""

    def __post_init__(self) -> None:
        require(self.mode in ("drop", "improved"), f"place mode must be 'drop' or 'improved', got {self.mode!r}")
        require(self.region[0] < self.region[1] and self.region[2] < self.region[3], "place region must be x0<x1, y0<y1")
        require(all(abs(v) <= 3.0 for v in self.region), "place region must lie within 3 m of the body")
        require_range(self, "drop_height improved_height", 0.0, 1.0)
        require_range(self, "top_band approach_inset", 0.0, 1.0)
        require_range(self, "surface_cell", 0.001, 0.5)
        require_range(self, "mask_erosion_px", 0, 100)


@dataclass(frozen=True)
class AgentConfig:
    """One agent, every variant of the paper's tables as flags."""

    variant: Literal["helios", "no_global", "trusting"] = "helios"
    """``helios``: the full method; ``no_global``: 'w/o global search objective' (any candidate
    pick location is searched before any frontier); ``trusting``: 2D maps only, goes to the
    highest-value frontier and trusts the first detection of the object / goal receptacle."""
    max_pick_attempts: int = 0
    """Grasp attempts before giving up (the paper reports 1, 5 and unlimited); 0 = unlimited."""
    max_looks_per_candidate: int = 6
    """Extra views of one target / goal candidate before it is left (a safety net: the decision
    rule stops asking for views once they cannot raise Psi by tau_inc)."""
    fresh_view_distance: float = 0.0
    """An extra view of a candidate (the Psi' rule's "take another view") comes from the gaze
    point with the best predicted Psi' among those at least this far (m) from where earlier extra
    views of it were taken, while any is left. 0 (default, the paper's rule read literally): the
    best predicted view, which is the same gaze point again and again, since the prediction does
    not know where the earlier views came from. A detector sees the same frame the same way, so
    repeated views from one spot add little: in train-00063 all seven views of the orange came
    from one gaze point without the robot moving, its Psi crept from 0.38 to 0.47 and stopped
    below tau_object = 0.5, the looks ran out, and the robot searched elsewhere until the time
    ran out, 330 s later (with 0.3 it grasps and succeeds at 370 s). Measured with 0.3 on the
    first 100 train episodes: Pick 38 against 38 (+4 -4), SR 12 against 13 (+3 -4), timeouts 25
    against 25: views from elsewhere lower Psi as often as they raise it, so the default stays."""
    fresh_gaze_after_failure: bool = True
    """A goal found unreachable drops the gaze points cached for the current frame, so a failed
    view is not chosen again at once; False restores the earlier behaviour (the same failing gaze
    point was offered until the next frame, which burned a candidate's ``max_looks_per_candidate``
    in zero time)."""
    max_failures_per_candidate: int = 2
    """Grasp or place failures on one candidate before it is no longer tried."""
    require_start_support: bool = True
    """HELIOS variants only grasp a target candidate that rests on a mapped start-receptacle
    candidate ('move X *from* Y'); the trusting agent grasps the first detection wherever it is."""
    support_radius: float = 0.35
    """Horizontal distance (m) from a target candidate to the footprint of its supporting receptacle."""
    frontier_reach: float = 0.8
    """Going to a frontier ends within this distance (m) of its centre."""
    frontier_approach: float = 0.0
    """When no path reaches within ``frontier_reach`` of a frontier, walk to within this distance
    (m) of it instead (1.5 was measured), look towards it from there and count it as reached; 0
    (default) marks it unreachable at once. The planner walks only where the whole body width has
    been seen, and a doorway is often seen as a strip narrower than that from across the room.
    One of three exploration fixes measured together and left off; see ``frontier_parts``."""
    frontier_blacklist_radius: float = 0.6
    """Frontiers within this (m) of one already reached or found unreachable are skipped."""
    frontier_parts: bool = False
    """True: standing near one end of a frontier does not reach it. Going to a frontier aims at
    its centre or any of (up to 16 of) its cells that are not within ``frontier_reach`` of the
    robot; when there are none, the robot looks towards it from where it stands and those parts
    count as reached while the frontier stays on offer with the rest; walking to one and
    arriving reaches the whole frontier; a frontier whose first step is blocked is marked
    unreachable rather than chosen again from the same spot. False (default, the earlier
    reading): a plan that starts within ``frontier_reach`` of *any* of its cells "arrives"
    without a step and reaches the whole frontier. A room's frontier through a doorway is one
    long curve that often passes within a metre of where the robot stands: in train-00034 a
    13.8 m frontier into the next room touched the start, was counted as reached at once, and
    HELIOS gave up after 82 s with the rest of the house unseen (with the fixes: success).
    Measured with ``frontier_approach=1.5`` and ``unstick_distance=0.5`` on the first 100 train
    episodes (README, "Exploration that gives up early"): "not found" 14 against 19, but FindObj
    53 against 55 (+5 -7) and SR 11 against 11 (+6 -6), timeouts 35 against 33; the episodes
    that no longer give up run out of time or fail later instead, so the defaults stay."""
    turn_bumps: Literal["sweep", "ahead"] = "ahead"
    """Where a walk that bumped into something while turning in place puts the obstacle it
    missed. ``ahead`` (default, the earlier code): beyond the footprint in the direction of the
    walk's next straight stretch, as for a bump while walking. ``sweep``: in the cells the body
    would sweep over the next 10 degrees of the turn that no frame has seen (all of them when
    every one was seen): a turn hits with a corner or a leg, often the rear swinging into floor
    behind the body that the hand camera never saw. In train-00018 a turn's hind leg hit a
    counter behind the robot; ``ahead`` put the obstacle on the free floor to its left, which
    with the unseen counter behind left no move but a 10 cm step back, and HELIOS gave up ("not
    found") after 113 s. ``sweep`` changed 3 of the first 100 train records of helios, all for the
    better (train-00018 finds and picks its object; 37 -> 28 collisions), but on the first 200 val
    episodes trusting with it found the object in 6 episodes fewer (+0 -6, p = 0.03; 26 records
    changed): there the marked sweep hemmed the robot in and it gave up after 78-101 s. The sweep's
    sides lie within the planner's robot radius of the body's centre line, so they also take the
    robot's own place out of the free space; hence off (README, "A bump while turning")."""
    unstick_distance: float = 0.0
    """When a plan is blocked at its first step (the path exists but the footprint cannot turn or
    step onto it: wedged beside furniture or in a doorway's corner), step straight, keeping the
    heading (Spot walks in any direction), to the nearest pose within this distance (m) where the
    body can turn all the way round, then plan again; once per place (0.5 was measured). 0
    (default): give up on the goal at once, which ends some "not found" episodes early with "no
    path: blocked" for every goal. Measured with the other exploration fixes; see
    ``frontier_parts``."""
    stall_steps: int = 6
    """Give up on a frontier (mark it unreachable) when, after a step towards it, this many more
    steps in a row towards it each end within ``stall_radius`` of where that first one ended and
    together add less than ``stall_new_area`` of explored floor (``frontier_goals.StallWatch``);
    0: never (the behaviour before 2026-12-04). Why: an exploration step can repeat itself for
    the rest of the episode: walk towards a frontier beside a wall, step back to give the arm
    room (``make_room``), look over floor already seen, choose the same frontier again. Of the
    25 timeouts among the first 100 train episodes, train-00020, -00058, -00086 and -00092
    spent 26 to 138 such steps in a row (up to 450 s of the 600), and train-00022 114 steps of
    the planner's shuffle loop (see ``planner.blocked_without_progress``).
    Most loops end by themselves within a few rounds (the robot drifts until the arm has room):
    a guard that fired after two such steps changed 18 of those 100 records and cost 3 successes,
    so the count to give up after is set well above the few rounds a loop that ends needs. With 6,
    on those 100 train episodes (decided there) 6 records changed: the five loops above end "not
    found" (4) or in a failed grasp of the target (train-00086, FindObj +1) instead of timing
    out, and train-00099 times out instead of ending "not found" (the frontier given up was not
    its last); timeouts 21 against 25, every other metric the same."""
    stall_radius: float = 0.5
    """See ``stall_steps``: how far (m) from where the first of the stalled steps ended the
    others may end."""
    stall_new_area: float = 0.25
    """See ``stall_steps``: explored floor (m^2) the stalled steps may add between them."""
    face_unseen: bool = True
    """Looking from a frontier (on arrival, or when every part of it is within reach): face the
    never-seen side of the frontier nearest the robot (``frontier_goals.unseen_bearing`` within
    ``frontier_reach`` + 1 m), turning the body in place first when that side lies more than 90
    degrees off its heading and the map leaves room to turn. False (the behaviour before
    2026-12-02): face the frontier's centre on arrival, straight ahead otherwise. Why: the robot
    often arrives standing on the frontier, heading the way it walked, with the unseen floor
    beside or behind it; the arm then looks ahead over seen floor, the frontier counts as
    reached, and a wedged robot ends the episode "not found" (train-00014 with gt semantics:
    given up after 88 s with the room behind the robot never looked at). Default since
    2026-12-02, decided on train: on the first 100 train episodes FindObj 55 against 55, FindRec
    28 against 22 (+12 -6), SR 13 against 11, timeouts 25 against 33 (README, "Where the misses
    come from")."""
    max_revisits: int = 4
    """When no frontier is left, up to this many walks to the most promising seen places (value
    map) to look again before giving up."""
    revisit_spacing: float = 1.5
    """Revisited places are at least this far (m) from each other and from the robot."""
    revisit_candidates: int = 8
    """The planner tries this many best places at once (the nearest reachable one wins)."""
    gaze_goal_radius: float = 0.15
    """Walking to a gaze point or grasp pose ends within this (m) of it."""
    gaze_hop: float = 1.5
    """A gaze point within this distance (m) is reached by one straight holonomic move that turns
    while it walks (Spot walks in any direction), when the footprint's sweep along it is free and
    seen; farther ones, or blocked hops, take the planner's rotate-then-forward actions. 0 is the
    paper's action set alone (its planner only moves forward and rotates; the default until
    2026-12-07). Going round a table from one gaze point to the next with those means turn ~90
    degrees, walk 0.6 m, turn back: ~6 s of the ~10 s a gaze point costs. Default 1.5 since
    2026-12-07, with ``local_search_views=informative``, chosen on train with Jeffreys' prior
    (200 episodes: timeouts 32 against 39, FindObj 70.5 against 65.0, SR 17.5 against 17.0;
    docs/search-experiments.md, "Cheaper local search again"). The informative views alone did
    not cut timeouts (40 on train): the hop is what turns the saved gaze points into time. With
    the flat prior (2026-12-01) the pair saved local-search time but not timeouts."""
    max_walk_chunks: int = 8
    """Plan-walk-look cycles allowed to reach one gaze point or grasp pose."""
    local_search_views: Literal["all", "informative"] = "informative"
    """Which of a candidate pick location's gaze points local search visits: ``all`` (the paper's
    local search section; the default until 2026-12-07) or ``informative`` (the default): a
    greedy subset by information gain, each added view raising the IG of those before it by at
    least ``local_search_min_gain`` of the IG of all of them
    (``helios.search.information.informative_views``; the paper's Discussion names "filtering for
    informative gaze points" as the way to make local search cheaper). It visits 3.0 instead of
    5.3 gaze points per local search on train; see ``gaze_hop`` for the outcome and the choice."""
    end_local_search_on_doubt: bool = False
    """End a local search (the location counts as searched) as soon as the location is no longer
    a candidate pick location: its instance merged away, or its class score fell below cs_a or
    another class became the most likely. The paper visits every gaze point of a location once
    chosen (False, default); with look-alike receptacles a closer view often shows that a
    "desk" is a table, and about a fifth of local-search gaze point visits on train were spent
    on such locations."""
    local_search_min_gain: float = 0.1
    """See ``local_search_views``: the smallest useful share of the location's total IG."""
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    gaze: GazeConfig = field(default_factory=GazeConfig)
    view: ViewConfig = field(default_factory=ViewConfig)
    reach: ReachConfig = field(default_factory=ReachConfig)
    place: PlaceConfig = field(default_factory=PlaceConfig)

    def __post_init__(self) -> None:
        require(self.variant in ("helios", "no_global", "trusting"),
                 f"variant must be helios, no_global or trusting, got {self.variant!r}")
        require(self.max_pick_attempts >= 0, "max_pick_attempts must be >= 0 (0 = unlimited)")
        require(self.max_looks_per_candidate >= 0 and self.max_failures_per_candidate >= 1,
                 "need max_looks_per_candidate >= 0 and max_failures_per_candidate >= 1")
        require(self.frontier_reach > 0 and self.gaze_goal_radius > 0, "radii must be > 0")
        require_range(self, "max_pick_attempts max_looks_per_candidate max_revisits", 0, 100000)
        require_range(self, "max_failures_per_candidate revisit_candidates max_walk_chunks", 1, 100000)
        require_range(self, "support_radius frontier_blacklist_radius revisit_spacing", 0.0, 100.0)
        require_range(self, "frontier_reach gaze_goal_radius", 0.0, 100.0, lo_open=True)
        require_range(self, "frontier_approach", 0.0, 100.0)
        require_range(self, "unstick_distance", 0.0, 3.0)
        require(self.turn_bumps in ("sweep", "ahead"), f"turn_bumps must be 'sweep' or 'ahead', got {self.turn_bumps!r}")
        require_range(self, "gaze_hop", 0.0, 10.0)
        require_range(self, "fresh_view_distance", 0.0, 10.0)
        require_range(self, "stall_steps", 0, 100000)
        require_range(self, "stall_radius", 0.0, 10.0, lo_open=True)
        require_range(self, "stall_new_area", 0.0, 1000.0)
        require(self.local_search_views in ("all", "informative"),
                f"local_search_views must be 'all' or 'informative', got {self.local_search_views!r}")
        require_range(self, "local_search_min_gain", 0.0, 1.0)

    @property
    def flags(self) -> "VariantFlags":
        """The variant as the typed switches the one code path reads."""
        return VariantFlags.of(self.variant)


@dataclass(frozen=True)
class VariantFlags:
    """What a variant switches on or off, so the agent reads typed flags, never variant names.

    ``object_map``: the Gaussian layer with Psi decisions and gaze points (HELIOS); without it
    the agent keeps 2D maps only and trusts the first detection of the object / goal receptacle
    (the trusting baseline). ``pick_objective``: how the pick phase chooses between candidate pick
    locations and frontiers (:class:`helios.search.objective.GlobalObjective` modes)."""

    object_map: bool
    pick_objective: Literal["objective", "prefer_candidates", "frontiers_only"]

    @staticmethod
    def of(variant: str) -> "VariantFlags":
        return {"helios": VariantFlags(True, "objective"),
                "no_global": VariantFlags(True, "prefer_candidates"),
                "trusting": VariantFlags(False, "frontiers_only")}[variant]
