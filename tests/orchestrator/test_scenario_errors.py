"""Malformed scenarios: each gives a clear message naming the culprit, a non-zero exit, no traceback."""
import subprocess
import sys
import zipfile

import pytest

from immersim.orchestrator.errors import FmuLoadError, ImmersimError, ScenarioError
from immersim.orchestrator.execution import Execution

GOOD_UNITS = '''
[[units]]
name = "m1"
fmu = "{fmu}"
[[units]]
name = "m2"
fmu = "{fmu}"
'''

CASES = [
    # (id, scenario text, expected error type, regex the message must match)
    ("bad_toml", '[simulation\nstop = 1', ScenarioError, r"invalid TOML"),
    ("no_units", '[simulation]\nstop = 1.0\n', ScenarioError, r"bad.toml: units: missing \(required\)"),
    ("unknown_top_key", 'foo = 1\n' + GOOD_UNITS, ScenarioError, r"bad.toml: unknown key 'foo' \(expected one of connections, description, faults"),
    ("step_zero", '[simulation]\nstep = 0.0\n' + GOOD_UNITS, ScenarioError, r"bad.toml: simulation.step: must be > 0, got 0.0"),
    ("step_negative", '[simulation]\nstep = -0.033\n' + GOOD_UNITS, ScenarioError, r"bad.toml: simulation.step: must be > 0, got -0.033"),
    ("stop_before_start", '[simulation]\nstart = 2.0\nstop = 1.0\n' + GOOD_UNITS, ScenarioError,
     r"simulation.stop = 1 s must be after simulation.start = 2 s"),
    ("bad_connection_extrapolation", GOOD_UNITS + '[[connections]]\nfrom = "m1.x"\nto = "m2.x_other"\n'
     'extrapolation = "cubic"\n', ScenarioError, r"connections\[0\].extrapolation: 'cubic' is not one of zoh, linear, angle"),
    ("bad_algorithm", '[simulation]\nalgorithm = "newton"\n' + GOOD_UNITS, ScenarioError,
     r"simulation.algorithm: 'newton' is not one of gauss-seidel, jacobi"),
    ("duplicate_instance", GOOD_UNITS + '[[units]]\nname = "m1"\nfmu = "{fmu}"\n', ScenarioError,
     r"duplicate unit instance name 'm1'"),
    ("unknown_unit_in_connection", GOOD_UNITS + '[[connections]]\nfrom = "m9.x"\nto = "m2.x_other"\n',
     ScenarioError, r"unknown unit 'm9' in 'm9.x'"),
    ("unknown_variable", GOOD_UNITS + '[[connections]]\nfrom = "m1.xx"\nto = "m2.x_other"\n', ScenarioError,
     r"unit m1 \(oscillator.fmu\) has no variable 'xx'"),
    ("wrong_causality_src", GOOD_UNITS + '[[connections]]\nfrom = "m1.x_other"\nto = "m2.x_other"\n', ScenarioError,
     r"source m1.x_other has causality input, expected output"),
    ("wrong_causality_dst", GOOD_UNITS + '[[connections]]\nfrom = "m1.x"\nto = "m2.v"\n', ScenarioError,
     r"destination m2.v has causality output, expected input"),
    ("connection_syntax", 'connections = ["m1.x => m2.x_other"]\n' + GOOD_UNITS, ScenarioError,
     r"is not of the form 'unit.out -> unit.in'"),
    ("input_twice", GOOD_UNITS + '[[connections]]\nfrom = "m1.x"\nto = "m2.x_other"\n'
     '[[connections]]\nfrom = "m1.v"\nto = "m2.x_other"\n', ScenarioError, r"input m2.x_other is already connected"),
    ("parameter_type", GOOD_UNITS.replace('fmu = "{fmu}"\n[[units]]', 'fmu = "{fmu}"\nparameters = {{ m = "heavy" }}\n[[units]]', 1),
     ScenarioError, r"parameter m1.m: type mismatch, the FMU declares Real but the scenario gives str 'heavy'"),
    ("unknown_parameter", GOOD_UNITS.replace('fmu = "{fmu}"\n[[units]]', 'fmu = "{fmu}"\nparameters = {{ mass = 2.0 }}\n[[units]]', 1),
     ScenarioError, r"unit m1 \(oscillator.fmu\) has no variable 'mass'"),
    ("missing_fmu", '[[units]]\nname = "a"\nfmu = "nowhere/missing.fmu"\n', FmuLoadError,
     r"unit a: FMU 'nowhere/missing.fmu' not found"),
    ("corrupt_fmu", '[[units]]\nname = "a"\nfmu = "{corrupt}"\n', FmuLoadError,
     r"unit a: FMU file .*corrupt.fmu is not a valid zip archive"),
    ("bad_input_kind", GOOD_UNITS + '[[inputs]]\ntarget = "m1.x_other"\nkind = "square"\n', ScenarioError,
     r"inputs\[0\]: kind 'square' is not one of"),
    ("input_missing_param", GOOD_UNITS + '[[inputs]]\ntarget = "m1.x_other"\nkind = "sine"\namplitude = 1.0\n',
     ScenarioError, r"inputs\[0\].frequency: missing \(required\)"),
    ("log_selects_nothing", GOOD_UNITS + '[log]\ninclude = ["nothing.*"]\n', ScenarioError,
     r"selects no output of any unit"),
    ("bad_unit_name", '[[units]]\nname = "my unit"\nfmu = "{fmu}"\n', ScenarioError,
     r"units\[0\].name: must be an identifier \(letters, digits, _ and -\), got 'my unit'"),
]


@pytest.fixture
def corrupt_fmu(tmp_path):
    p = tmp_path / "corrupt.fmu"
    p.write_bytes(b"PK\x03\x04 this is not really a zip archive")
    return p


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_malformed_scenario(tmp_path, test_fmus, corrupt_fmu, case):
    _, text, exc_type, pattern = case
    scn = tmp_path / "bad.toml"
    scn.write_text(text.format(fmu=test_fmus["oscillator"], corrupt=corrupt_fmu))
    with pytest.raises(exc_type, match=pattern) as info:
        Execution(scn).run()
    assert isinstance(info.value, ImmersimError)
    if exc_type is ScenarioError and "bad.toml" not in str(info.value):
        pytest.fail(f"message does not name the file: {info.value}")


def test_at_least_twelve_cases():
    assert len(CASES) >= 12


def test_cli_reports_without_traceback(tmp_path, test_fmus):
    scn = tmp_path / "bad.toml"
    scn.write_text('[simulation]\nstep = 0.0\n' + GOOD_UNITS.format(fmu=test_fmus["oscillator"]))
    proc = subprocess.run([sys.executable, "-m", "immersim.orchestrator.cli", "run", str(scn)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.startswith("immersim: error: ")
    assert proc.stderr.endswith("bad.toml: simulation.step: must be > 0, got 0.0\n")
    assert proc.stderr.count("\n") == 1
    assert "Traceback" not in proc.stderr


def test_corrupt_member_in_valid_zip(tmp_path, test_fmus):
    """A zip that is an FMU in name only: modelDescription.xml is garbage."""
    p = tmp_path / "garbled.fmu"
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("modelDescription.xml", "<fmiModelDescription")
    scn = tmp_path / "g.toml"
    scn.write_text(f'[[units]]\nname = "g"\nfmu = "{p}"\n')
    with pytest.raises(FmuLoadError, match=r"unit g: .*garbled.fmu: (invalid|cannot read) modelDescription.xml"):
        Execution(scn).run()
