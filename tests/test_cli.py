"""The theory command line: readable table, JSON, clear errors."""
import json
import subprocess
import sys


def run(*args):
    return subprocess.run([sys.executable, "-m", "microhom", *args], capture_output=True, text=True)


def test_predict_seed_case_table():
    p = run("predict")
    assert p.returncode == 0, p.stderr
    assert "fraction change" in p.stdout
    assert "0.189" in p.stdout and "0.284" in p.stdout


def test_predict_json_broadcast():
    p = run("predict", "--kt", "0", "1e8", "--nc", "4.1", "4.5", "--json")
    assert p.returncode == 0, p.stderr
    rows = json.loads(p.stdout)
    assert len(rows) == 4
    assert {r["kt"] for r in rows} == {0.0, 1e8}
    assert all(r["valid"] for r in rows)


def test_predict_bad_value_names_parameter():
    p = run("predict", "--phi", "1.2")
    assert p.returncode == 2
    assert "phi" in p.stderr and "0.9069" in p.stderr
    p = run("predict", "--kn", "abc")
    assert p.returncode == 2 and "kn must be a number" in p.stderr


def test_help_explains_units():
    p = run("predict", "--help")
    assert p.returncode == 0
    for text in ("N/m", "var(Nc)/Nc^2", "[0, 2]"):
        assert text in p.stdout
