"""Seeded fuzz of the file readers: any mutation of a valid recording or scenario file is either read
(finite numbers, uniform ids) or refused with the reader's own error, never another exception."""

from __future__ import annotations

import random
import time

import numpy as np
import pytest

from tapmuscle.cosim.spec import ScenarioError, load_scenario
from tapmuscle.io.recording import RecordingError, read_recording

VALID_CSV = "# ts_s: 0.1\n# load_n: 44\nt_s,u_v,l_mm,p_mpa\n" + "".join(
    f"{k / 10:g},{5 + 3 * np.sin(k / 10):.6f},{30 + 10 * np.sin(k / 10 - 0.3):.4f},0.1{k % 10}\n" for k in range(60))
VALID_TOML = """name = "fuzz"
duration_s = 12.0
step_s = 0.1
seed = 3
evaluation_samples = [10, 100]
[controller]
method = "ampc_servo"
[controller.parameters]
"servo.R" = 15.0
[reference]
kind = "sine"
offset_mm = 35.0
amplitude_mm = 30.0
frequency_hz = 0.1
[load]
initial_n = 44
steps = [{ t_s = 5.0, load_n = 68.0 }]
"""
ALPHABET = list("0123456789.,-+eE\n\r\t #:=[]{}\"'_abcdefnaiNf") + ["nan", "inf", "1e309", "\ufeff", "\x00", "é"]


def _mutate(text: str, rng: random.Random) -> str:
    chars = list(text)
    for _ in range(rng.randint(1, 6)):
        op = rng.random()
        i = rng.randrange(len(chars) + 1)
        if op < 0.35 and chars:
            del chars[min(i, len(chars) - 1)]
        elif op < 0.7:
            chars.insert(i, rng.choice(ALPHABET))
        elif op < 0.85 and chars:
            chars[min(i, len(chars) - 1)] = rng.choice(ALPHABET)
        else:  # drop or duplicate a whole line
            lines = "".join(chars).split("\n")
            j = rng.randrange(len(lines))
            lines.insert(j, lines[j]) if rng.random() < 0.5 else lines.pop(j)
            chars = list("\n".join(lines))
    return "".join(chars)


@pytest.mark.parametrize("seed", range(4))
def test_mutated_recordings_are_read_or_refused(tmp_path, seed):
    rng = random.Random(seed)
    path = tmp_path / "r.csv"
    deadline = time.monotonic() + 10.0
    outcomes = {"read": 0, "refused": 0}
    for _ in range(150):
        path.write_text(_mutate(VALID_CSV, rng), encoding="utf-8", errors="surrogatepass")
        try:
            rec = read_recording(path)
        except RecordingError as exc:
            assert str(exc) and "\n" not in str(exc)
            outcomes["refused"] += 1
        else:
            assert all(np.all(np.isfinite(v)) for v in rec.columns.values())
            assert np.all(np.diff(rec.t_s) > 0)
            try:
                assert rec.ts_s > 0
            except RecordingError:
                pass
            outcomes["read"] += 1
        if time.monotonic() > deadline:
            break
    assert outcomes["read"] and outcomes["refused"]  # the mutations exercise both paths


@pytest.mark.parametrize("seed", range(4))
def test_mutated_scenarios_are_read_or_refused(tmp_path, seed):
    rng = random.Random(100 + seed)
    path = tmp_path / "s.toml"
    outcomes = {"read": 0, "refused": 0}
    deadline = time.monotonic() + 10.0
    for _ in range(150):
        path.write_text(_mutate(VALID_TOML, rng), encoding="utf-8", errors="surrogatepass")
        try:
            s = load_scenario(path)
        except ScenarioError as exc:
            assert str(exc).startswith(str(path)) or str(path) in str(exc)
            outcomes["refused"] += 1
        else:
            assert s.n_samples >= 2 and 0 <= s.seed < 2 ** 64 and s.duration_s > 0
            outcomes["read"] += 1
        if time.monotonic() > deadline:
            break
    assert outcomes["read"] and outcomes["refused"]
