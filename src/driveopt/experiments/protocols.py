"""Declared protocols of the figures of P1 and P2: what ``driveopt reproduce`` runs and what each claim compares.

A :class:`FigureProtocol` holds a figure's claims, its seeds, episodes and episode duration; a :class:`Claim`
compares one :class:`Arm` (a registered planner with its bench options) with another on the same episodes and names
the paper's value or stated direction. Each arm says whether it is the paper's method as the paper and its authors'
code ran it (``FAITHFUL``: the ``*-faithful`` planners of :mod:`driveopt.faithful`, and P1's RL agents), driveopt's
strengthened version (``STRENGTHENED``) or a reference (``REFERENCE``: highway-env's IDM driver); each claim is a
faithful row, a driveopt row or a mixed one (:attr:`Claim.kind`), and every figure compares the faithful methods and
driveopt's side by side. A figure that cannot be run with the registered planners declares why (``not_run``) and has
no claims.

Choices where the papers are silent (each also listed in ``docs/reproduction/README.md``):

* Seeds 42 and 123 for every figure (DESIGN.md: the authors' seeds), 50 episodes per seed, 50 s episodes.
* P1 Figs. 7, 8: 250 samples per sampler iteration for the bi-level optimisers (P1 §V-F: the benchmarks of §V-C and
  V-D used 250); the faithful MPC baselines run their authors' 1000 (every expert of the authors' ``expert_mpc/``).
* P1's faithful MPC-Bi-Level in Figs. 7, 8, 12 is ``cvae-faithful``: the authors' ``main_bilevel.py``, which their
  README names as the script of the main results, starts Alg. 1 from the CVAE. Fig. 9 compares it with
  ``bilevel-faithful`` (Alg. 1's Gaussian start as the authors' code draws it).
* P1 Fig. 7 twice: driveopt's ``bilevel`` against driveopt's ``random``, ``grid``, ``batch``, ``vanilla``, and
  ``cvae-faithful`` against ``random-faithful``, ``grid-faithful``, ``batch-faithful``, ``vanilla-faithful``; all of
  them plan every 0.1 s (the authors' loops plan once per simulator step for every method).
* P1's densities: ``two-lane-d1.0`` and ``two-lane-d2.5``, ``four-lane-d1.5`` and ``four-lane-d3.0``; P1 Fig. 8 on
  ``two-lane-d1.0`` (P1: the RL agents worked only in sparse two-lane traffic) and ``four-lane-d3.0``; P1 Fig. 9 on
  ``four-lane-d3.0``; P1 Fig. 12 on ``two-way``.
* P2 Fig. 7's settings: densities 1.5 and 3.0 at neighbour speed limits 15 and 7 m/s on four lanes (P2's text
  names density 3 and the two limits only).
* P2 Fig. 7 also judges ``vqvae-filter`` against ``vqvae`` on its episodes (collisions, speed, plan time, each "no
  worse"): whether the learned filter changes anything against the plain one, which P2 does not measure.
* P2's baseline [5], a CVAE trained through the projection that predicts its multipliers, is ``cvae-multipliers``
  and, as [5]'s authors ran it, ``cvae-multipliers-faithful`` (shipped four-lane weights). Beside it, P2 Figs. 7 and 9
  keep ``cvae-filter`` and ``cvae-filter-faithful``: P1's CVAE through P2's one-pass filter.
* P2 Fig. 9's "without filter" is ``projection.max_iterations`` 0: for driveopt's pipelines the samples ranked as
  drawn, feasibility first, which is rejection sampling; for the faithful ones P2's pick by cost + residual,
  executed whatever its residual, which is P2's no-filter.
* P2 Figs. 8a, 8b: the faithful pipeline enters the text's claim (the reduced budget against the full one); the
  learned against the plain filter at every point is compared for driveopt's pipelines only.

Quick variants (:meth:`FigureProtocol.quick`): seed 42 only, 2 episodes of 4 s, a tenth of the samples (at least
10); the claims and arms are those of the full protocol.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from driveopt.errors import DriveoptError

FAITHFUL, STRENGTHENED, REFERENCE = "paper-faithful", "driveopt-strengthened", "reference"
FAITHFUL_ROW, DRIVEOPT_ROW, MIXED_ROW = "faithful", "driveopt", "driveopt vs faithful"  # Claim.kind
COLLISIONS, SPEED, PLAN_TIME = "collisions", "speed", "plan time"
BETTER, WORSE, NO_WORSE = "better", "worse", "no worse"  # of the claim's arm against its baseline, on its metric

SEEDS = (42, 123)  # traffic seeds of every full protocol
EPISODES = 50  # [-] per scenario, planner and seed
QUICK_SEEDS = (42,)
QUICK_EPISODES = 2  # [-] per scenario, planner and seed
QUICK_DURATION = 4.0  # [s] per episode
QUICK_SAMPLE_DIVISOR = 10  # quick arms draw samples // 10 (at least QUICK_MIN_SAMPLES) per sampler iteration
QUICK_MIN_SAMPLES = 10


class ProtocolError(DriveoptError):
    """An unknown paper or figure, or a protocol option out of range."""


@dataclass(frozen=True)
class Arm:
    """A registered planner as one figure runs it.

    samples: per sampler iteration [-] (None: the planner's own); replan_every: policy periods of 0.1 s each plan is
    executed (None: the planner's own); config: planner-config overrides as (dotted key, value) pairs, e.g.
    ``(("projection.max_iterations", 0),)``; version: FAITHFUL, STRENGTHENED or REFERENCE; note: how it departs
    from the paper's method, when it does."""

    planner: str
    version: str
    samples: int | None = None
    replan_every: int | None = None
    config: tuple[tuple[str, Any], ...] = ()
    note: str = ""

    @property
    def label(self) -> str:
        """The planner and the options it runs with, e.g. ``bilevel-p1 n250 r5``."""
        parts = [self.planner]
        if self.samples is not None:
            parts.append(f"n{self.samples}")
        if self.replan_every is not None:
            parts.append(f"r{self.replan_every}")
        parts += [f"{key.rpartition('.')[2]}={value}" for key, value in self.config]
        return " ".join(parts)

    def options(self, duration: float | None) -> dict[str, Any]:
        """The bench options of this arm (``driveopt.experiments.bench.episode_record``); duration [s] or None."""
        options: dict[str, Any] = {}
        if self.samples is not None:
            options["samples"] = self.samples
        if self.replan_every is not None:
            options["replan_every"] = self.replan_every
        config: dict[str, Any] = {}
        for key, value in self.config:
            *sections, name = key.split(".")
            node = config
            for section in sections:
                node = node.setdefault(section, {})
            node[name] = value
        if config:
            options["config"] = config
        if duration is not None:
            options["duration"] = duration
        return options

    def folder(self, duration: float | None) -> str:
        """The bench folder (under the figure's) of every arm with these options: equal options share one."""
        tags = [f"n{self.samples}" if self.samples is not None else "nown"]
        if self.replan_every is not None:
            tags.append(f"r{self.replan_every}")
        tags += [f"{key.rpartition('.')[2].replace('_', '')}{value}" for key, value in self.config]
        if duration is not None:
            tags.append(f"t{duration:g}s")
        return "-".join(tags)

    def quick(self) -> "Arm":
        samples = None if self.samples is None else max(QUICK_MIN_SAMPLES, self.samples // QUICK_SAMPLE_DIVISOR)
        return dataclasses.replace(self, samples=samples)


@dataclass(frozen=True)
class Claim:
    """``arm`` against ``baseline`` on ``scenario``, on the same episodes: the paper says ``arm`` is ``expect``
    (BETTER, WORSE or NO_WORSE) on ``metric`` (COLLISIONS: fewer is better; SPEED, collision-free episodes: higher
    is better; PLAN_TIME per call: lower is better). ``paper``: the paper's value or stated direction, as it gives
    it. ``explanation``: why driveopt's result may contradict the paper and the experiment that settles it (the
    report prints it under a contradicted row, and flags a contradicted row without one). ``question``: the tag of a
    paper's :class:`Question` this claim also answers (its pairs are pooled with those of the other claims so tagged)."""

    scenario: str
    arm: Arm
    baseline: Arm
    metric: str
    expect: str
    paper: str
    explanation: str = ""
    question: str = ""  # the tag of the :class:`Question` whose pooled answer this claim's episodes enter

    @property
    def kind(self) -> str:
        """FAITHFUL_ROW when both arms are faithful (a reference aside), DRIVEOPT_ROW when both are driveopt's
        strengthened planners (or a reference), MIXED_ROW otherwise."""
        versions = {self.arm.version, self.baseline.version} - {REFERENCE}
        if versions == {FAITHFUL}:
            return FAITHFUL_ROW
        return DRIVEOPT_ROW if versions <= {STRENGTHENED} else MIXED_ROW

    @property
    def like_for_like(self) -> bool:
        """Both arms are the same kind of version (both faithful or both driveopt's)."""
        return self.kind != MIXED_ROW

    @property
    def name(self) -> str:
        return f"{self.scenario}: {self.arm.label} vs {self.baseline.label}, {self.metric}"

    def quick(self) -> "Claim":
        return dataclasses.replace(self, arm=self.arm.quick(), baseline=self.baseline.quick())


@dataclass(frozen=True)
class FigureProtocol:
    """One figure of one paper: claims, seeds, episodes per seed and episode duration [s] (None: the scenario's,
    50 s). ``not_run``: why the figure is not run (then ``claims`` is empty). ``reduced``: a quick or otherwise
    reduced variant, whose rows say so; ``full_episodes``: episodes per claim of the full protocol."""

    paper: str
    figure: str
    title: str
    claims: tuple[Claim, ...] = ()
    seeds: tuple[int, ...] = SEEDS
    episodes: int = EPISODES
    duration: float | None = None
    not_run: str = ""
    reduced: bool = False
    full_episodes: int = EPISODES * len(SEEDS)

    def runs(self) -> dict[str, tuple[tuple[str, ...], tuple[str, ...], dict[str, Any]]]:
        """``{folder: (scenarios, planners, options)}``: the bench runs this figure needs, one per set of options."""
        runs: dict[str, tuple[list[str], list[str], dict[str, Any]]] = {}
        for claim in self.claims:
            for arm in (claim.arm, claim.baseline):
                scenarios, planners, _ = runs.setdefault(arm.folder(self.duration), ([], [], arm.options(self.duration)))
                if claim.scenario not in scenarios:
                    scenarios.append(claim.scenario)
                if arm.planner not in planners:
                    planners.append(arm.planner)
        return {folder: (tuple(s), tuple(p), o) for folder, (s, p, o) in runs.items()}

    def quick(self) -> "FigureProtocol":
        return dataclasses.replace(self, claims=tuple(c.quick() for c in self.claims), seeds=QUICK_SEEDS,
                                   episodes=QUICK_EPISODES, duration=QUICK_DURATION, reduced=True)

    def with_runs(self, seeds: tuple[int, ...] | None = None, episodes: int | None = None) -> "FigureProtocol":
        """This protocol with other seeds or episodes per seed; fewer episodes in all than the full protocol mark
        it reduced."""
        changed = dataclasses.replace(self, seeds=tuple(seeds) if seeds else self.seeds,
                                      episodes=episodes if episodes else self.episodes)
        smaller = len(changed.seeds) * changed.episodes < self.full_episodes
        return dataclasses.replace(changed, reduced=self.reduced or smaller)


@dataclass(frozen=True)
class Question:
    """A question the paper does not settle, answered on every episode pair of the claims tagged ``tag`` (on the same
    metric; an episode of the same two arms on the same scenario counts once, whichever figures judge it): does the
    arm change collisions, speed or plan time against the baseline? ``min_pairs``: the pairs the answer needs."""

    tag: str
    title: str
    min_pairs: int


# ---------------------------------------------------------------------------------------------------------- P1
P1_SAMPLES = 250  # [-] P1 §V-F: the batch of the bi-level optimiser in the benchmarks of §V-C and V-D
P1_BASELINE_SAMPLES = 1000  # [-] the faithful MPC baselines' batch (their authors' num_batch; given so --quick divides it)
P1_DENSE = ("four-lane-d3.0", "two-lane-d2.5")
P1_SPARSE = ("four-lane-d1.5", "two-lane-d1.0")
IDM = Arm("idm", REFERENCE)
FAITHFUL_BILEVEL = "cvae-faithful"  # P1's MPC-Bi-Level: its authors' main_bilevel.py starts Alg. 1 from the CVAE
FAITHFUL_BILEVEL_NOTE = ("P1's MPC-Bi-Level as its authors' main_bilevel.py runs it: CVAE start (driveopt's shipped "
                         "weights), 5 x 20 iterations, P1's ranking, a plan every 0.1 s")
FAITHFUL_MPC_NOTES = {  # P1 §V-A3's baselines as the authors' expert_mpc/ runs them; all: P1's ranking, a plan every 0.1 s
    "random": "1000 samples from N((v_des, y0), diag(16, 46)), 100 projection iterations, P1's ranking, a plan every 0.1 s",
    "grid": "the authors' 50 speeds x 20 offsets, 100 projection iterations, P1's ranking, a plan every 0.1 s",
    "batch": ("goals on the authors' 50 x 20 grid (their Batch-MPC file is not public), 100 projection iterations, "
              "P1's ranking, a plan every 0.1 s"),
    "vanilla": ("v_des only, the 1000 least obstructed of 30000 guesses, 100 projection iterations, P1's ranking, a "
                "plan every 0.1 s"),
}


def _strong(planner: str, samples: int | None = P1_SAMPLES, **kw: Any) -> Arm:
    return Arm(planner, STRENGTHENED, samples, **kw)


def _faithful(planner: str, samples: int | None = P1_SAMPLES, note: str = "") -> Arm:
    return Arm(planner, FAITHFUL, samples, note=note)


def _p1_figure7() -> FigureProtocol:
    bilevel = _strong("bilevel")
    ours = _faithful(FAITHFUL_BILEVEL, note=FAITHFUL_BILEVEL_NOTE)
    claims = []
    for scenario in P1_DENSE + P1_SPARSE:
        dense = scenario in P1_DENSE
        for baseline in ("random", "grid", "batch", "vanilla"):
            if dense:
                collisions = ("4-10x fewer collisions than every MPC baseline" if scenario.startswith("four")
                              else "fewer collisions (improvement 'distinctly apparent')")
                expect = BETTER
            elif scenario.startswith("two") and baseline != "random":
                collisions, expect = "0% for every baseline but MPC-Random", NO_WORSE
            elif scenario.startswith("two"):
                collisions, expect = "MPC-Random collides, the others do not", BETTER
            else:
                collisions, expect = "no explicit value (figure only)", NO_WORSE
            speed = "average speed 'either better or competitive'"
            faithful_base = _faithful(f"{baseline}-faithful", P1_BASELINE_SAMPLES, FAITHFUL_MPC_NOTES[baseline])
            for arm, base in ((bilevel, _strong(baseline)), (ours, faithful_base)):
                claims.append(Claim(scenario, arm, base, COLLISIONS, expect, collisions))
                claims.append(Claim(scenario, arm, base, SPEED, NO_WORSE, speed))
    return FigureProtocol("p1", "fig7", "MPC baselines against the bi-level optimiser, two and four lanes, two densities",
                          tuple(claims))


def _p1_rl(figure: str, title: str, scenarios: tuple[str, ...], paper: dict[str, str]) -> FigureProtocol:
    claims = []
    for scenario in scenarios:
        for agent in ("dqn", "ppo"):
            rl = Arm(agent, FAITHFUL, note="P1's agent, trained 10 000 of P1's 5 M steps (shipped policy)")
            for arm in (_strong("bilevel"), _faithful(FAITHFUL_BILEVEL, note=FAITHFUL_BILEVEL_NOTE)):
                claims.append(Claim(scenario, arm, rl, COLLISIONS, BETTER, paper["collisions"]))
                claims.append(Claim(scenario, arm, rl, SPEED, BETTER, paper["speed"]))
    return FigureProtocol("p1", figure, title, tuple(claims))


def _p1_start_pairs(samples: int) -> tuple[tuple[Arm, Arm], ...]:
    """(CVAE start, Gaussian start) at ``samples``: driveopt's and the faithful pair."""
    return ((_strong("cvae", samples), _strong("bilevel-p1", samples, note="P1's Gaussian start, driveopt's machinery")),
            (_faithful(FAITHFUL_BILEVEL, samples, FAITHFUL_BILEVEL_NOTE),
             _faithful("bilevel-faithful", samples, "P1's Gaussian start as its authors' code draws it")))


def _p1_figure9() -> FigureProtocol:
    claims = []
    for samples, paper in ((250, "4x fewer collisions with the CVAE start at 250 samples"),
                           (1000, "fewer collisions with the CVAE start at 1000 samples; the gap shrinks")):
        for cvae, gauss in _p1_start_pairs(samples):
            claims.append(Claim("four-lane-d3.0", cvae, gauss, COLLISIONS, BETTER, paper))
            claims.append(Claim("four-lane-d3.0", cvae, gauss, SPEED, NO_WORSE, "not stated"))
    return FigureProtocol("p1", "fig9", "CVAE start against the Gaussian start, 250 and 1000 samples", tuple(claims))


def _p1_figure10() -> FigureProtocol:
    claims = tuple(Claim("four-lane-d3.0", cvae, gauss, PLAN_TIME, NO_WORSE,
                         f"CVAE inference overhead 'very minimal'; {t} s per call on an RTX 3080")
                   for n, t in ((250, "0.03"), (1000, "< 0.06")) for cvae, gauss in _p1_start_pairs(n))
    return FigureProtocol("p1", "fig10", "planning time per call, CVAE against Gaussian start (closed-loop calls)", claims)


def p1_figures() -> tuple[FigureProtocol, ...]:
    """P1 Figs. 7-12 in order."""
    return (
        _p1_figure7(),
        _p1_rl("fig8", "RL baselines (DQN, PPO) against the bi-level optimiser", ("two-lane-d1.0", "four-lane-d3.0"),
               {"collisions": "DQN and PPO 'drastically worse'", "speed": "DQN and PPO slower"}),
        _p1_figure9(),
        _p1_figure10(),
        FigureProtocol("p1", "fig11", "the two-way scenario (an illustration)",
                       not_run="an illustration of the scenario, nothing to measure (driveopt drive --scenario two-way "
                               "--video FILE renders it); its results are Fig. 12"),
        _p1_rl("fig12", "two-way road: RL baselines against the bi-level optimiser", ("two-way",),
               {"collisions": "0% for the MPC approaches, RL collides", "speed": "MPC approaches faster than RL"}),
    )


# ---------------------------------------------------------------------------------------------------------- P2
P2_SAMPLES = 1000  # [-] P2's batch
P2_ITERATIONS = 100  # [-] filter iterations of P2's pipeline
BASELINE_NOTE = "P2's baseline [5]: a CVAE trained through the projection that predicts its multipliers"
FAITHFUL_BASELINE_NOTE = f"{BASELINE_NOTE}; as [5]'s authors ran it (least residual + speed error, executed whatever its residual)"
CVAE_BESIDE_NOTE = "P1's CVAE through P2's one-pass filter (beside P2's baseline [5], cvae-multipliers)"
FAITHFUL_P2_NOTE = "P2's ranking (cost + residual), executed whatever its residual, no driveopt safety machinery"
NO_FILTER_EXPLANATION = (
    "driveopt's planner without the filter is rejection sampling: it ranks feasible samples first and brakes when none "
    "is feasible, so the filter, which makes more samples feasible, lets it brake less; P2's no-filter executes its "
    "best-ranked sample whatever its residual. The faithful rows of this figure (P2's ranking, no driveopt machinery) "
    "are the experiment that settles which effect P2 measured.")
NO_FILTER_NOTES = {STRENGTHENED: "no filter: feasibility-first ranking (rejection sampling)",
                   FAITHFUL: "no filter"}  # the faithful arms' note adds P2's ranking


def _p2_arm(planner: str, version: str = STRENGTHENED, samples: int = P2_SAMPLES, iterations: int | None = None,
            note: str = "") -> Arm:
    """driveopt's pipeline ``planner`` (STRENGTHENED) or its faithful version (FAITHFUL: ``<planner>-faithful``, its
    note adding P2's ranking); ``iterations``: filter iterations (None: the planner's 100)."""
    if version == FAITHFUL:
        planner, note = f"{planner}-faithful", "; ".join(part for part in (note, FAITHFUL_P2_NOTE) if part)
    config = () if iterations is None else (("projection.max_iterations", iterations),)
    return Arm(planner, version, samples, config=config, note=note)


def _p2(planner: str, samples: int = P2_SAMPLES, iterations: int | None = None, note: str = "") -> Arm:
    return _p2_arm(planner, STRENGTHENED, samples, iterations, note)


def _baseline(version: str, iterations: int | None = None, note: str = "") -> Arm:
    """P2's baseline [5] (``cvae-multipliers``, its faithful version ``cvae-multipliers-faithful``); ``iterations``:
    projection iterations (None: [5]'s 75)."""
    planner, described = (("cvae-multipliers", BASELINE_NOTE) if version == STRENGTHENED
                          else ("cvae-multipliers-faithful", FAITHFUL_BASELINE_NOTE))
    config = () if iterations is None else (("projection.max_iterations", iterations),)
    return Arm(planner, version, P2_SAMPLES, config=config, note="; ".join(part for part in (described, note) if part))


P2_FIGURE7_SCENARIOS = ("p2-four-lane-d1.5", "p2-four-lane-d3.0", "p2-four-lane-d1.5-slow", "p2-four-lane-d3.0-slow")
LEARNED_FILTER_CLAIM = "the learned filter is proposed to make the one pass safer (no value against the plain filter)"
LEARNED_FILTER = Question("learned-filter", "the learned filter against the plain one (`vqvae-filter` against `vqvae`)",
                          min_pairs=150)


def _p2_figure7() -> FigureProtocol:
    claims = []
    learned, plain = _p2("vqvae-filter", note="P2's pipeline with the learned filter"), _p2("vqvae", note="plain filter")
    learned_faithful = _p2_arm("vqvae-filter", FAITHFUL, note="P2's pipeline with the learned filter")
    pairs = tuple((arm, base) for base, base_faithful in (
        (_baseline(STRENGTHENED), _baseline(FAITHFUL)),
        (_p2("cvae-filter", note=CVAE_BESIDE_NOTE), _p2_arm("cvae-filter", FAITHFUL, note=CVAE_BESIDE_NOTE)))
        for arm, base in ((learned, base), (plain, base), (learned_faithful, base_faithful)))
    for scenario in P2_FIGURE7_SCENARIOS:
        paper = ("up to 12x fewer collisions than the CVAE baseline (density 3)" if "d3.0" in scenario
                 else "fewer collisions than the CVAE baseline as density rises or traffic slows")
        for arm, base in pairs:
            claims.append(Claim(scenario, arm, base, COLLISIONS, BETTER, paper))
            claims.append(Claim(scenario, arm, base, SPEED, NO_WORSE, "similar velocity profiles"))
        # The learned filter against the plain one on the same episodes (both ran above): does it change anything?
        for metric in (COLLISIONS, SPEED, PLAN_TIME):
            claims.append(Claim(scenario, learned, plain, metric, NO_WORSE, LEARNED_FILTER_CLAIM,
                                question=LEARNED_FILTER.tag))
    return FigureProtocol("p2", "fig7", "VQ-VAE against the CVAE baseline, two densities and two speed limits",
                          tuple(claims))


def _p2_budget(figure: str, title: str, points: tuple[tuple[int, int], ...], reduced: tuple[int, int],
               paper: str) -> FigureProtocol:
    """Fig. 8a/8b: (samples, iterations) points; the reduced budget against P2's full one (driveopt's pipeline and the
    faithful one), and driveopt's learned filter against its plain one at each point (collisions, speed, plan time)."""
    scenario = "p2-four-lane-d3.0"

    def iterations(k: int) -> int | None:
        return None if k == P2_ITERATIONS else k

    def learned(n: int, k: int) -> Arm:
        return _p2("vqvae-filter", n, iterations(k))

    def faithful(n: int, k: int) -> Arm:
        return _p2_arm("vqvae-filter", FAITHFUL, n, iterations(k))

    claims = [Claim(scenario, pipeline(*reduced), pipeline(P2_SAMPLES, P2_ITERATIONS), COLLISIONS, NO_WORSE, paper)
              for pipeline in (learned, faithful)]
    for n, k in points:
        claims += [Claim(scenario, learned(n, k), _p2("vqvae", n, iterations(k)), metric, NO_WORSE, LEARNED_FILTER_CLAIM,
                         question=LEARNED_FILTER.tag) for metric in (COLLISIONS, SPEED, PLAN_TIME)]
    return FigureProtocol("p2", figure, title, tuple(claims))


def _p2_figure9() -> FigureProtocol:
    claims = []
    for density in ("1.0", "1.5", "3.0"):
        scenario = f"p2-four-lane-d{density}"
        for version in (STRENGTHENED, FAITHFUL):
            vq = _p2_arm("vqvae-filter", version)
            vq0 = _p2_arm("vqvae-filter", version, iterations=0, note=NO_FILTER_NOTES[version])
            b5, b50 = _baseline(version), _baseline(version, iterations=0, note=NO_FILTER_NOTES[version])
            cv = _p2_arm("cvae-filter", version, note=CVAE_BESIDE_NOTE)
            cv0 = _p2_arm("cvae-filter", version, iterations=0, note=f"{CVAE_BESIDE_NOTE}; {NO_FILTER_NOTES[version]}")
            if density != "3.0":
                for without in (b50, cv0):
                    claims.append(Claim(scenario, vq0, without, COLLISIONS, BETTER, "CVAE without filter 8x more collisions"))
            else:
                for with_filter, without in ((vq, vq0), (b5, b50), (cv, cv0)):
                    claims.append(Claim(scenario, with_filter, without, COLLISIONS, BETTER,
                                        "the filter is needed at high density"))
            for with_filter, without in ((vq, vq0), (b5, b50), (cv, cv0)):
                claims.append(Claim(scenario, with_filter, without, SPEED, WORSE,
                                    "the filter makes the car more conservative (slower)",
                                    NO_FILTER_EXPLANATION if version == STRENGTHENED else ""))
    return FigureProtocol("p2", "fig9", "with and without the safety filter, densities 1.0, 1.5, 3.0", tuple(claims))


def p2_figures() -> tuple[FigureProtocol, ...]:
    """P2 Figs. 1, 7, 8a, 8b, 9 in order."""
    return (
        FigureProtocol("p2", "fig1", "CVAE against VQ-VAE samples (offline KDE)",
                       not_run="an offline figure of the priors' samples at one observation, not a closed-loop "
                               "comparison: driveopt plot-prior draws it (docs/results/learned-prior.md)"),
        _p2_figure7(),
        _p2_budget("fig8a", "filter iterations 10, 25, 50, 100, learned against plain filter",
                   tuple((P2_SAMPLES, k) for k in (10, 25, 50, 100)), (P2_SAMPLES, 50),
                   "collision rate 'mere 3%' at 50 iterations"),
        _p2_budget("fig8b", "samples 250, 500, 750, 1000, learned against plain filter",
                   tuple((n, P2_ITERATIONS) for n in (250, 500, 750, 1000)), (750, P2_ITERATIONS),
                   "collision rate 'only increased to 4%' at 750 samples"),
        _p2_figure9(),
    )


PAPERS = {"p1": p1_figures, "p2": p2_figures}
QUESTIONS: dict[str, tuple[Question, ...]] = {"p1": (), "p2": (LEARNED_FILTER,)}  # answered by each paper's report


def figures_of(paper: str, names: list[str] | tuple[str, ...] | None = None, *, quick: bool = False,
               seeds: tuple[int, ...] | None = None, episodes: int | None = None) -> tuple[FigureProtocol, ...]:
    """The protocols of ``paper`` ('p1' or 'p2'), only ``names`` (e.g. 'fig7') when given, in the paper's order;
    quick variants with ``quick``; ``seeds``/``episodes`` replace those of every figure. ProtocolError for an
    unknown paper or figure, a figure named twice."""
    if paper not in PAPERS:
        raise ProtocolError(f"unknown paper {paper!r}; valid: {', '.join(PAPERS)}")
    figures = PAPERS[paper]()
    if names:
        known = [f.figure for f in figures]
        unknown = [n for n in names if n not in known]
        if unknown:
            raise ProtocolError(f"{paper} has no figure {', '.join(unknown)}; its figures: {', '.join(known)}")
        if len(set(names)) < len(names):
            raise ProtocolError(f"figures {list(names)}: give each once")
        figures = tuple(f for f in figures if f.figure in names)
    if quick:
        figures = tuple(f.quick() for f in figures)
    if seeds or episodes:
        figures = tuple(f.with_runs(seeds, episodes) for f in figures)
    return figures
