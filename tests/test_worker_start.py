"""Worker processes refused up front where they cannot start (tapmuscle/cosim/worker_start.py)."""

import subprocess
import sys
import textwrap


def test_workers_asked_for_inside_a_pools_daemonic_worker_are_refused_naming_the_setting(tmp_path):
    """``tm.diagnose(..., workers=2)`` inside a ``multiprocessing.Pool`` worker: multiprocessing's own
    refusal is a bare ``AssertionError: daemonic processes are not allowed to have children``; the
    refusal names the setting and the remedy. A ``ProcessPoolExecutor``'s worker (not daemonic) may."""
    script = tmp_path / "nested.py"
    script.write_text(textwrap.dedent("""
        import concurrent.futures
        import multiprocessing

        def ask(_):
            from tapmuscle.cosim.worker_start import check_workers_can_start
            try:
                check_workers_can_start("workers=2")
            except Exception as exc:
                return f"{type(exc).__name__}: {exc}"
            return "allowed"

        if __name__ == "__main__":
            spawn = multiprocessing.get_context("spawn")
            with spawn.Pool(1) as pool:
                print(pool.map(ask, [0])[0])
            with concurrent.futures.ProcessPoolExecutor(1, mp_context=spawn) as pool:
                print(list(pool.map(ask, [0]))[0])
    """))
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    in_pool, in_executor = out.stdout.splitlines()
    assert in_pool.startswith("UsageError: workers=2 starts worker processes, and this process is a daemonic one")
    assert "give 1 worker inside it" in in_pool
    assert in_executor == "allowed"
