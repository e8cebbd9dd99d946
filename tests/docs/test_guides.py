"""Each extension guide in docs/guides/ is followed here, code block by code block, so that a guide
that drifts from the code fails: a throwaway method ("flat") registered for the test, and a
throwaway source kind ("wall") installed in a temporary folder with its entry point."""

from __future__ import annotations

import doctest
import importlib.util
import re
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import measure.distance
import measure.options

ROOT = Path(__file__).resolve().parents[2]
GUIDES = ROOT / "docs" / "guides"
FENCE = re.compile(r"^```(\w+)\n(.*?)^```", re.S | re.M)


def blocks(page: Path) -> list[tuple[str, str, str]]:
    """(language, first-line path comment or "", code) of every fenced block of ``page``, in order."""
    out = []
    for lang, code in FENCE.findall(page.read_text()):
        first = code.splitlines()[0] if code else ""
        out.append((lang, first[2:].strip() if lang == "python" and first.startswith("# ") else "", code))
    return out


def run_pycon(code: str, globs: dict) -> doctest.TestResults:
    test = doctest.DocTestParser().get_doctest(code, globs, "guide", None, 0)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    runner.run(test)
    return runner.summarize(verbose=False)


def test_adding_a_measurement(tmp_path, monkeypatch):
    steps = blocks(GUIDES / "measurement.md")
    assert [(lang, path) for lang, path, _ in steps] == [
        ("python", "measure/flat.py"), ("python", "measure/options.py"), ("python", "measure/distance.py"),
        ("pycon", ""), ("python", "tests/measure/test_flat.py")]
    (_, _, module), (_, _, names), (_, _, registry), (_, _, session), (_, _, test) = steps

    # 1. The module, importable as measure.flat for this test only.
    (tmp_path / "flat.py").write_text(module)
    spec = importlib.util.spec_from_file_location("measure.flat", tmp_path / "flat.py")
    flat = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "measure.flat", flat)
    spec.loader.exec_module(flat)

    # 2. Its name: today's METHODS plus the new one.
    ns: dict = {}
    exec(names, ns)
    assert ns["METHODS"][:-1] == measure.options.METHODS and ns["METHODS"][-1] == "flat"
    monkeypatch.setattr(measure.options, "METHODS", ns["METHODS"])

    # 3. The registry as the guide writes it: today's entries, in order, plus one line.
    ns = dict(vars(measure.distance))
    exec(registry, ns)
    new = ns["METHOD_IMPLEMENTATIONS"]
    old = measure.distance.METHOD_IMPLEMENTATIONS
    assert list(new)[:-1] == list(old) and all(new[k] is old[k] for k in old)
    assert new["flat"] is flat.measure_flat
    monkeypatch.setattr(measure.distance, "METHOD_IMPLEMENTATIONS", new)

    # 4. The session's printed answers.
    result = run_pycon(session, {})
    assert result.attempted >= 5 and result.failed == 0

    # 5. The guide's test, every test function of it.
    ns = {"__name__": "guide_test"}
    exec(test, ns)
    tests = [fn for name, fn in ns.items() if name.startswith("test_")]
    assert len(tests) == 2
    for fn in tests:
        fn()


def test_a_method_that_drifted_fails(tmp_path):
    """The session block is checked: a wrong printed answer is a failure, not a pass."""
    *_, (_, _, session), _ = blocks(GUIDES / "measurement.md")
    assert run_pycon(session.replace("(method=\"flat\")", "(method=\"basic\")"), {}).failed == 1


SESSION = textwrap.dedent('''
    import doctest, sys
    parser, runner = doctest.DocTestParser(), doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    runner.run(parser.get_doctest(open(sys.argv[1]).read(), {}, "guide", None, 0))
    result = runner.summarize(verbose=False)
    sys.exit(0 if result.attempted and not result.failed else 1)
''')


def test_adding_a_source_kind(tmp_path):
    steps = blocks(GUIDES / "source.md")
    assert [(lang, path) for lang, path, _ in steps] == [("python", "depthruler_wall.py"), ("toml", ""), ("pycon", "")]
    (_, _, module), (_, _, toml), (_, _, session) = steps
    # The package as pip would install it: the module and a dist-info with the guide's entry point.
    (tmp_path / "depthruler_wall.py").write_text(module)
    dist = tmp_path / "depthruler_wall-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: depthruler-wall\nVersion: 0.1\n")
    points = tomllib.loads(toml)["project"]["entry-points"]
    lines = [f"[{group}]\n" + "".join(f"{name} = {value}\n" for name, value in eps.items()) for group, eps in points.items()]
    (dist / "entry_points.txt").write_text("\n".join(lines))
    (tmp_path / "session.txt").write_text(session)
    (tmp_path / "run.py").write_text(SESSION)
    env_path = f"{tmp_path}:{ROOT}"
    done = subprocess.run([sys.executable, str(tmp_path / "run.py"), str(tmp_path / "session.txt")], cwd=tmp_path,
                          env={"PYTHONPATH": env_path, "PATH": "/usr/bin:/bin"}, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    # Without the entry point the kind is unknown: the registration, not the module's presence, makes it.
    (dist / "entry_points.txt").write_text("")
    undone = subprocess.run([sys.executable, str(tmp_path / "run.py"), str(tmp_path / "session.txt")], cwd=tmp_path,
                            env={"PYTHONPATH": env_path, "PATH": "/usr/bin:/bin"}, capture_output=True, text=True, timeout=300)
    assert undone.returncode == 1 and "wall" in undone.stdout
