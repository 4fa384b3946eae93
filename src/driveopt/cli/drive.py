"""``driveopt drive``: one closed-loop episode with a progress bar, a summary, and an MP4 of the plans.

The video's frames follow the ego; on each, the sampled, elite and followed plans in world coordinates and a
heads-up display of time, speed, desired speed, planner, status and planning time (:mod:`driveopt.viz.overlay`).

``--json`` and ``--video`` are checked (a folder that can be written, ``.mp4`` for the video) before the episode
runs; both are written whole or not at all, and a video ffmpeg could not finish (a full disk) is an error, not
"wrote". The JSON is strict: a planner that never plans (``idm``) has null plan times. An episode whose every planning call
ended in NUMERICAL_ERROR (the car followed the fallback throughout) exits with status 1 after writing its outputs.
"""

from __future__ import annotations

import argparse
import contextlib
import sys

from driveopt.cli.common import config_overrides, positive_int, seed, writable_file, write_json
from driveopt.cli.parser import duration, latency


def register(sub) -> None:
    p = sub.add_parser("drive", help="drive one closed-loop episode in highway-env (progress, summary, MP4)")
    p.add_argument("--scenario", default="four-lane-d3.0", help="scenario name (see `driveopt scenarios`)")
    p.add_argument("--scenario-config", help="JSON file overriding scenario fields")
    p.add_argument("--planner", default="bilevel", help="planner name (see `driveopt planners`; default bilevel)")
    p.add_argument("--weights", help="learned-prior checkpoint, or policy file of dqn/ppo (default: the weights shipped for the road)")
    p.add_argument("--filter-weights", help="learned safety-filter checkpoint for any optimiser (vqvae-filter: default the shipped one)")
    p.add_argument("--seed", type=seed, default=42, help="traffic and sampling seed")
    p.add_argument("--duration", type=duration, help="episode length [s] (default: the scenario's)")
    p.add_argument("--samples", type=positive_int, help="samples per sampler iteration (default: the planner's)")
    p.add_argument("--replan-every", type=positive_int, help="policy periods each plan is executed open-loop (P1: 5; default 1)")
    p.add_argument("--latency", type=latency, metavar="sync|measured|MS",
                   help="sync (default): the simulator waits for every plan; measured: the car keeps executing the "
                        "previous plan while one is computed, which takes effect after its measured time rounded up "
                        "to policy periods; MS: a fixed compute time [ms] instead (deterministic)")
    p.add_argument("--video", default="out/drive.mp4", help="MP4 path, ending in .mp4 ('' for none)")
    p.add_argument("--json", help="write the episode summary as JSON here")
    p.add_argument("--config", help="planner config overrides, JSON (nested sections, e.g. {\"cost\": {\"consistency\": 1.0}})")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from driveopt.drivers.base import check_given_weights, with_samples_and_config
    from driveopt.experiments.rollout import Rollout
    from driveopt.registry import get_planner
    from driveopt.sim.scenarios import resolve_scenario
    from driveopt.viz.video import VIDEO_SUFFIXES

    writable_file(args.json, "--json")
    writable_file(args.video, "--video", VIDEO_SUFFIXES)
    scenario = resolve_scenario(args.scenario, config_file=args.scenario_config)
    if args.duration is not None:
        scenario = scenario.replace(duration=args.duration)
    spec = get_planner(args.planner)
    check_given_weights(spec, args.weights, args.filter_weights)  # a path that is no file, weights it takes no use of
    spec = with_samples_and_config(spec.with_weights(args.weights), args.samples,
                                   config_overrides(args.config, args.filter_weights)).with_replan_every(args.replan_every)
    check_given_weights(spec, filter_weights=getattr(spec, "filter_weights", None))  # or the --config file's
    spec = spec.with_latency(args.latency)
    spec.check(scenario)  # missing, unusable or wrong-road weights: the error comes before the progress bar
    steps = int(round(scenario.duration * scenario.policy_frequency))
    rollout = Rollout(scenario, spec.driver(), args.seed, render=bool(args.video))
    with contextlib.ExitStack() as stack:
        bar = stack.enter_context(tqdm(total=steps, desc=f"{scenario.name} / {spec.name}", unit="step"))
        bar.set_postfix_str("compiling")
        writer, planned = None, None
        if args.video:
            from driveopt.viz.overlay import render_decision
            from driveopt.viz.video import VideoWriter

            writer = stack.enter_context(VideoWriter(args.video, fps=scenario.policy_frequency))
        for step in rollout:
            result = step.decision.result
            if writer is not None:  # the state the plan was made from, before the simulator steps
                planned = step.decision if result is not None or planned is None else planned  # open-loop: the last plan
                writer.append(render_decision(step.env, planned, planner=spec.name, v_des=scenario.v_des, v_des_source="scenario",
                                              config=getattr(rollout.driver, "config", None)))
            episode = step.episode
            if not episode.speeds:  # the first step came after compilation: time the rest from here
                bar.reset(total=steps)
            bar.update(1)
            bar.set_postfix(v=f"{episode.speeds[-1]:.1f}" if episode.speeds else "-",
                            plan_ms=f"{1e3 * step.decision.plan_seconds:.0f}" if result is not None else "-")
    episode = rollout.episode
    summary = episode_summary(episode)
    planning = ("no planning calls" if summary["plan_ms_median"] is None else
                f"planning {summary['plan_ms_median']:.0f} ms median / {summary['plan_ms_p95']:.0f} ms p95")
    if "plan_periods_median" in summary:  # real time: the plans took effect this many policy periods after they started
        planning += (f" (in effect after {summary['plan_periods_median']:.0f} periods median, "
                     f"{summary['plan_periods_max']} at most)")
    print(
        f"{scenario.name} / {spec.name} (seed {args.seed}): collided {episode.collided}, off-road {episode.off_road}, "
        f"{episode.sim_duration:.1f} s simulated, mean speed {episode.mean_speed:.1f} m/s, {planning}, "
        f"compile {episode.compile_seconds:.1f} s"
    )
    if args.json:
        print(f"  wrote {write_json(args.json, summary)}")
    if args.video:
        print(f"  wrote {args.video}")
    if summary["statuses"] and set(summary["statuses"]) == {"NUMERICAL_ERROR"}:
        print(f"driveopt: error: every planning call of {spec.name} ended in NUMERICAL_ERROR (the car followed the "
              "fallback throughout); check the planner configuration", file=sys.stderr)
        return 1
    return 0


def episode_summary(episode) -> dict:
    """The episode's JSON summary; the plan-time statistics are null (missing) when it made no planning call."""
    summary = episode.summary()
    if not episode.plan_ms:
        summary.update(plan_ms_median=None, plan_ms_p95=None)
    return summary
