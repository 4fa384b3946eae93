"""Time of P2's learned proposal: PixelCNN sampling, VQ-VAE decoder and set-point QP.

    python benchmarks/perf/vqvae_sampling.py --json out/vqvae_sampling.json [--samples 1000] [--calls 30] [--resume]
        [--reference] [--untrained]

For each batch size, on the built-in problem ``dense-snapshot`` (one observation), four jitted
functions are timed separately:

- ``pixelcnn``: L = 10 code indices per sample drawn autoregressively, incrementally and once per distinct
  prefix (``px.sample_codes``: at step i only each layer's output at position i, from cached earlier columns);
- ``decoder``: codes -> codebook -> decoder MLP -> bounded set-points (codes drawn once, shifted by a
  random offset per call);
- ``setpoint_qp``: set-points -> Bernstein coefficients and the 100 positions (closed-form batch QP;
  set-points drawn once, perturbed per call);
- ``pipeline``: all three in one compiled function, exactly what the ``vqvae`` planner's proposal runs
  (``VQVAEPrior.propose``: sample, decode, clip, moments) followed by the set-point QP;
- ``pixelcnn_reference`` (only with ``--reference``): the same draws by re-running the whole network
  over all L positions for each position (``px.sample_codes_reference``, one ``fori_loop``; L times the work).

The prior is the shipped four-lane one (``vqvae-four-lane.ckpt``): the sampler computes each distinct prefix of
the codes once, so its work follows the trained distribution's spread, and the JSON records how many distinct
prefixes the timed draws had at each position. ``--untrained`` times freshly initialised networks of the same
sizes instead, whose nearly uniform codes make almost every prefix distinct: the most work a call can take. The
parameters are arguments of the jitted functions, as in the planner, compiled with the planner's CPU options.

Compile time is the first call minus the steady-state median; steady state is the median and p90 of
``--calls`` calls with fresh PRNG keys (``block_until_ready`` on the outputs). Results are written after every
case; ``--resume`` keeps finished cases.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from driveopt.config import PlannerConfig
from driveopt.files import write_json
from driveopt.learned import pixelcnn as px
from driveopt.learned import vqvae as vq
from driveopt.learned.cvae import FEATURE_DIM
from driveopt.priors.vqvae import VQVAEPrior, load_prior, shipped_weights
from driveopt.problem import build_problem
from driveopt.qp import make_model, qp_layer
from driveopt.scene import load_scene
from driveopt.xla import XLA_CPU_COMPILER_OPTIONS, supported_compiler_options

STAGES = ("pixelcnn", "decoder", "setpoint_qp", "pipeline")
SAMPLER = ("incremental and once per distinct prefix: step i computes each distinct prefix's output at position i "
           "only, from the cached outputs at positions i - k//2 .. i of the layer below (px.sample_codes); "
           "pixelcnn_reference re-runs the network over all positions per step")


def untrained_prior(seed: int = 0) -> VQVAEPrior:
    """The VQ-VAE prior with the shipped configuration's sizes and freshly initialised parameters."""
    vq_cfg = vq.VQVAEConfig()
    px_cfg = px.PixelCNNConfig.for_vqvae(vq_cfg)
    k_vq, k_px = jax.random.split(jax.random.PRNGKey(seed))
    nodes = vq_cfg.basis.num_nodes
    normaliser = vq.Normaliser(jnp.zeros(FEATURE_DIM), jnp.ones(FEATURE_DIM), jnp.zeros((nodes, 2)), jnp.ones((nodes, 2)))
    return VQVAEPrior(vq.init_params(vq_cfg, k_vq), normaliser, px.init_params(px_cfg, k_px), vq_cfg, px_cfg,
                      PlannerConfig().projection.v_max)


def parameter_count(tree) -> int:
    return int(sum(np.size(leaf) for leaf in jax.tree_util.tree_leaves(tree)))


def timed(fn: Callable[[jax.Array], object], calls: int) -> dict:
    """compile_s (first call minus the median), median_ms and p90_ms over ``calls`` steady-state calls."""
    start = time.perf_counter()
    jax.block_until_ready(fn(jax.random.PRNGKey(0)))
    first = time.perf_counter() - start
    times = []
    for i in range(calls):
        key = jax.random.PRNGKey(i + 1)
        start = time.perf_counter()
        jax.block_until_ready(fn(key))
        times.append(time.perf_counter() - start)
    median = float(np.median(times))
    return {"compile_s": max(first - median, 0.0), "median_ms": 1e3 * median, "p90_ms": 1e3 * float(np.percentile(times, 90))}


def stage_functions(prior: VQVAEPrior, samples: int) -> dict[str, Callable[[jax.Array], object]]:
    """One function of a PRNG key per stage (see the module docstring), each jitted with the prior as an argument."""
    config = PlannerConfig()
    problem = build_problem(load_scene("dense-snapshot"), config.basis)
    model = make_model(config.basis, config.qp)
    feats = vq.features(problem.observation, prior.normaliser, prior.vqvae_config)
    obs = jnp.broadcast_to(problem.observation, (samples, problem.observation.shape[-1]))
    lanes = jnp.broadcast_to(jnp.stack([problem.y_lb, problem.y_ub]), (samples, 2))
    codes = px.sample_codes(prior.pixelcnn_params, prior.pixelcnn_config, feats, jax.random.PRNGKey(0), samples)
    setpoints = prior.propose(problem, jax.random.PRNGKey(0), samples).samples
    K = prior.vqvae_config.codebook_size  # fresh inputs per call: the codes shifted by a random offset
    options = {"compiler_options": supported_compiler_options(XLA_CPU_COMPILER_OPTIONS)} if jax.default_backend() == "cpu" else {}

    def qp(p):
        return qp_layer(model, config.qp, p, problem.init_x, problem.init_y)

    stages = {
        "pixelcnn": lambda prior, key: px.sample_codes(prior.pixelcnn_params, prior.pixelcnn_config, feats, key, samples),
        "decoder": lambda prior, key: vq.decode_codes(prior.vqvae_params, prior.vqvae_config, prior.normaliser,
                                                      (codes + jax.random.randint(key, (), 0, K)) % K, obs, lanes),
        "setpoint_qp": lambda prior, key: qp(setpoints + jax.random.normal(key, setpoints.shape)),
        "pipeline": lambda prior, key: qp(prior.propose(problem, key, samples).samples),
        "pixelcnn_reference": lambda prior, key: px.sample_codes_reference(prior.pixelcnn_params, prior.pixelcnn_config,
                                                                           feats, key, samples),
    }
    return {name: (lambda fn: lambda key: fn(prior, key))(jax.jit(stage, **options)) for name, stage in stages.items()}


def distinct_prefixes(prior: VQVAEPrior, samples: int, calls: int) -> list[float]:
    """Median over the timed calls' draws of how many distinct prefixes (codes before position i) there are at each
    position i: the rows the sampler computes there."""
    problem = build_problem(load_scene("dense-snapshot"), PlannerConfig().basis)
    feats = vq.features(problem.observation, prior.normaliser, prior.vqvae_config)
    counts = []
    for i in range(calls):
        codes = np.asarray(px.sample_codes(prior.pixelcnn_params, prior.pixelcnn_config, feats, jax.random.PRNGKey(i + 1),
                                           samples))
        counts.append([len(np.unique(codes[:, :position], axis=0)) for position in range(codes.shape[1])])
    return np.median(counts, axis=0).tolist()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", default="out/vqvae_sampling.json", help="results file (updated after every case)")
    parser.add_argument("--samples", type=int, nargs="+", default=[1000], help="batch sizes (P2: 1000)")
    parser.add_argument("--calls", type=int, default=30, help="steady-state calls per case")
    parser.add_argument("--resume", action="store_true", help="keep finished cases of an existing results file")
    parser.add_argument("--reference", action="store_true", help="also time the full-recompute PixelCNN sampler (slow)")
    parser.add_argument("--untrained", action="store_true",
                        help="time freshly initialised networks (nearly every prefix distinct: the most work) instead of "
                             "the shipped four-lane prior")
    args = parser.parse_args(argv)
    if args.calls < 1 or min(args.samples) < 1:
        parser.error("--calls and --samples must be >= 1")

    parameters = "untrained" if args.untrained else "shipped four-lane"
    prior = untrained_prior() if args.untrained else load_prior(shipped_weights(4))
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    machine = {"platform": platform.platform(), "cpus": os.cpu_count(), "jax": jax.__version__, "device": str(jax.devices()[0])}
    models = {"vqvae_config": prior.vqvae_config.to_dict(), "pixelcnn_config": prior.pixelcnn_config.to_dict(),
              "vqvae_parameters": parameter_count(prior.vqvae_params), "pixelcnn_parameters": parameter_count(prior.pixelcnn_params),
              "parameters": parameters, "pixelcnn_sampler": SAMPLER}
    report = {"machine": machine, "models": models, "problem": "dense-snapshot", "load_before": os.getloadavg(),
              "results": []}
    if args.resume and path.exists():
        try:
            previous = json.loads(path.read_text())
            report["results"] = previous["results"]
        except (json.JSONDecodeError, KeyError) as exc:
            print(f"vqvae_sampling: error: cannot resume from {path}: {exc}", file=sys.stderr)
            return 2
        if previous.get("models", {}).get("parameters") != parameters:
            print(f"vqvae_sampling: error: {path} timed other parameters ({previous.get('models', {}).get('parameters')}); "
                  f"resume it with the same --untrained setting or write another file", file=sys.stderr)
            return 2
    done = {r["case"] for r in report["results"]}
    stages = STAGES + ("pixelcnn_reference",) * args.reference
    cases = [(n, stage) for n in args.samples for stage in stages if f"{stage}-{n}" not in done]
    functions: dict[int, dict] = {}
    for samples, stage in tqdm(cases, desc="vqvae_sampling", unit="case"):
        if samples not in functions:
            functions[samples] = stage_functions(prior, samples)
        result = {"case": f"{stage}-{samples}", "stage": stage, "samples": samples, "calls": args.calls,
                  **timed(functions[samples][stage], args.calls)}
        if stage == "pixelcnn":
            result["distinct_prefixes"] = distinct_prefixes(prior, samples, args.calls)
        report["results"].append(result)
        write_json(path, report)  # strict JSON, whole or not at all
        tqdm.write(f"{result['case']:>18}: compile {result['compile_s']:.2f} s, median {result['median_ms']:.2f} ms, "
                   f"p90 {result['p90_ms']:.2f} ms")
    report["load_after"] = os.getloadavg()
    write_json(path, report)
    print(f"wrote {path} (load average {report['load_before'][0]:.2f} before, {report['load_after'][0]:.2f} after)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
