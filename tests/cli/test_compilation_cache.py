"""JAX's persistent compilation cache: where driveopt puts it, how it is turned off, that a folder configured for JAX is
kept, and that two processes filling one folder at the same time both succeed and leave entries a third one loads."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

from driveopt.compilation_cache import ENV, cache_folder

# Prints, after driveopt's cache set-up (run when driveopt.xla is imported), JAX's cache settings as JSON.
STATE = textwrap.dedent("""
    import json, warnings
    warnings.simplefilter("always")
    with warnings.catch_warnings(record=True) as caught:
        import driveopt.xla
    import jax
    from driveopt.compilation_cache import enable_default
    print(json.dumps({"dir": jax.config.jax_compilation_cache_dir, "again": str(enable_default()),
                      "min_s": jax.config.jax_persistent_cache_min_compile_time_secs,
                      "max_size": jax.config.jax_compilation_cache_max_size,
                      "warnings": [str(w.message) for w in caught]}))
""")


def _state(**env: str) -> dict:
    environ = {k: v for k, v in os.environ.items() if not k.startswith("JAX_") and k != ENV}
    proc = subprocess.run([sys.executable, "-c", STATE], capture_output=True, text=True, timeout=120, env={**environ, **env},
                          check=False)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.splitlines()[-1])


def test_folder_from_the_environment(tmp_path):
    home = Path.home()
    assert cache_folder({}) == home / ".cache" / "driveopt" / "jax"
    assert cache_folder({"XDG_CACHE_HOME": str(tmp_path)}) == tmp_path / "driveopt" / "jax"
    assert cache_folder({"XDG_CACHE_HOME": "relative/path"}) == home / ".cache" / "driveopt" / "jax"  # the XDG rule
    assert cache_folder({ENV: "1", "XDG_CACHE_HOME": str(tmp_path)}) == tmp_path / "driveopt" / "jax"
    assert cache_folder({ENV: str(tmp_path / "mine")}) == tmp_path / "mine"
    for off in ("0", "off", "OFF", "false", "no", " 0 "):
        assert cache_folder({ENV: off}) is None


def test_on_by_default_in_a_private_folder(tmp_path):
    state = _state(XDG_CACHE_HOME=str(tmp_path))
    folder = tmp_path / "driveopt" / "jax"
    assert state["dir"] == str(folder) and state["again"] == str(folder) and state["warnings"] == []
    assert folder.is_dir() and folder.stat().st_mode & 0o777 == 0o700
    assert state["min_s"] == 0.5 and state["max_size"] > 0


def test_turned_off(tmp_path):
    state = _state(**{ENV: "0", "XDG_CACHE_HOME": str(tmp_path)})
    assert state["dir"] is None and state["again"] == "None" and not (tmp_path / "driveopt").exists()
    assert state["min_s"] == 1.0  # JAX's own settings untouched


def test_a_folder_configured_for_jax_is_kept(tmp_path):
    state = _state(JAX_COMPILATION_CACHE_DIR=str(tmp_path / "users"), **{ENV: str(tmp_path / "ours")})
    assert state["dir"] == str(tmp_path / "users") and not (tmp_path / "ours").exists()
    assert state["min_s"] == 1.0 and state["max_size"] == -1


def test_an_unusable_folder_is_one_warning_and_no_cache(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    state = _state(**{ENV: str(blocker / "jax")})
    assert state["dir"] is None and len(state["warnings"]) == 1
    assert state["warnings"][0].startswith("compilation cache off") and str(blocker) in state["warnings"][0]


# Compiles 12 distinct functions (every one cached: minimum compile time 0) once the start file exists, counting the
# cache hits; any error reading or writing the cache is raised.
FILL = textwrap.dedent("""
    import json, os, sys, time
    import driveopt.xla  # the cache, in DRIVEOPT_COMPILATION_CACHE
    import jax, jax.numpy as jnp
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_raise_persistent_cache_errors", True)
    hits = []
    jax.monitoring.register_event_listener(lambda event, **kw: hits.append(1) if event.endswith("/cache_hits") else None)
    while not os.path.exists(sys.argv[1]):
        time.sleep(0.005)
    total = 0.0
    for k in range(12):
        f = jax.jit(lambda x, k=k: jnp.sin(x @ x.T + k).sum() * (k + 1))
        total += float(f(jnp.ones((64 + k, 32))))
    print(json.dumps({"hits": len(hits), "total": total}))
""")


def test_two_processes_fill_one_folder_at_once(tmp_path):
    folder, start = tmp_path / "cache", tmp_path / "start"
    env = {**{k: v for k, v in os.environ.items() if not k.startswith("JAX_")}, ENV: str(folder)}
    procs = [subprocess.Popen([sys.executable, "-c", FILL, str(start)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, env=env) for _ in range(2)]
    start.touch()  # both wait for it after importing JAX: their compilations overlap
    results = [proc.communicate(timeout=300) for proc in procs]
    for proc, (out, err) in zip(procs, results):
        assert proc.returncode == 0, err
    first = [json.loads(out.splitlines()[-1]) for out, _ in results]
    entries = sorted(folder.glob("*-cache"))  # the 12 functions and JAX's own small computations (jnp.ones, ...)
    assert len([e for e in entries if e.name.startswith("jit__lambda-")]) == 12
    assert all(entry.stat().st_size > 0 for entry in entries)
    third = subprocess.run([sys.executable, "-c", FILL, str(start)], capture_output=True, text=True, timeout=300, env=env,
                           check=False)
    assert third.returncode == 0, third.stderr
    again = json.loads(third.stdout.splitlines()[-1])
    assert again["hits"] == len(entries) and again["total"] == first[0]["total"] == first[1]["total"]


def test_a_second_plan_loads_the_planner_from_the_cache(tmp_path):
    env = {**{k: v for k, v in os.environ.items() if not k.startswith("JAX_")}, ENV: str(tmp_path), "JAX_LOG_COMPILES": "1"}
    command = [sys.executable, "-m", "driveopt.cli", "plan", "--samples", "10", "--iterations", "2",
               "--projection-iterations", "2", "--repeats", "0"]
    runs = [subprocess.run(command, capture_output=True, text=True, timeout=600, env=env, check=False) for _ in range(2)]
    assert [run.returncode for run in runs] == [0, 0], runs[-1].stderr[-2000:]
    assert len(list(tmp_path.glob("jit_solve-*-cache"))) == 1
    hit = "Persistent compilation cache hit for 'jit_solve'"
    assert hit not in runs[0].stderr and hit in runs[1].stderr
    assert runs[0].stdout.splitlines()[1:4] == runs[1].stdout.splitlines()[1:4]  # the same plan (line 0: the compile time)
