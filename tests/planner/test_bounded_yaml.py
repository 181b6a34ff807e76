"""The shared bounded YAML reading (planner.bounded_yaml) and what reads through it: aliases, depth, size and
non-regular files are refused in one line naming the file, before anything is expanded or blocks."""
import os
import re
import subprocess
import sys

import pytest
from crafted_yaml import BILLION_LAUGHS, SELF_REFERENCE
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.assembly import load_assembly
from planner.block_calibration import load_block_calibration
from planner.bounded_yaml import MAX_DEPTH, YAMLInputError, load_yaml_file, parse_yaml
from planner.contours import load_catalog_object

pytestmark = pytest.mark.fast

LOAD_WITH_MEMORY_LIMIT = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))  # a loader that expands the document fails fast
from planner.assembly import load_assembly
from planner.block_calibration import load_block_calibration
from planner.contours import load_catalog_object
loader = {"assembly": load_assembly, "calibration": load_block_calibration,
          "catalog": lambda path: load_catalog_object("a", path)}[sys.argv[1]]
try:
    loader(sys.argv[2])
except ValueError as error:
    print(error)
"""


@pytest.mark.parametrize("reader", ["assembly", "calibration", "catalog"])
@pytest.mark.parametrize("text", [BILLION_LAUGHS, SELF_REFERENCE], ids=["billion_laughs", "self_reference"])
def test_every_project_file_refuses_aliases_in_one_line(tmp_path, reader, text):
    """In a child process with bounded memory and time: yaml.safe_load expanded a billion laughs for minutes."""
    path = tmp_path / "crafted.yaml"
    path.write_text(text)
    run = subprocess.run([sys.executable, "-c", LOAD_WITH_MEMORY_LIMIT, reader, str(path)], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 0, run.stderr[-1000:]
    assert re.search(r"crafted.yaml: invalid YAML: line 1, column \d+: anchors and aliases", run.stdout), run.stdout
    assert len(run.stdout) < 300


def test_depth_size_tabs_and_syntax_errors_are_one_line_without_the_document(tmp_path):
    with pytest.raises(YAMLInputError, match=rf"deep: invalid YAML: line 1, column 33: nested deeper than {MAX_DEPTH}"):
        parse_yaml("[" * 5000 + "]" * 5000, "deep")
    with pytest.raises(YAMLInputError, match=r"big: larger than 100 bytes"):
        parse_yaml("#" * 101, "big", max_size=100)
    with pytest.raises(YAMLInputError, match=r"tabbed: invalid YAML: line 2, column 1: found character '\\t'"):
        parse_yaml("a:\n\tb: secret_value\n", "tabbed")
    with pytest.raises(YAMLInputError, match=r"huge: invalid YAML: .*4300") as error:
        parse_yaml("a: " + "9" * 5000, "huge")
    assert "\n" not in str(error.value)
    broken = tmp_path / "broken.yaml"
    broken.write_text("name: secret_value\n  - x: [\n")
    with pytest.raises(YAMLInputError, match=r"broken.yaml: invalid YAML: line \d+, column \d+: ") as error:
        load_yaml_file(broken)
    assert "secret_value" not in str(error.value)


def test_a_fifo_and_a_device_are_refused_without_blocking(tmp_path):
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    for path in (fifo, "/dev/zero", tmp_path):
        with pytest.raises(YAMLInputError, match=rf"{re.escape(str(path))}: not a regular file"):
            load_yaml_file(path)
    with pytest.raises(YAMLInputError, match=r"missing.yaml: cannot read: No such file"):
        load_yaml_file(tmp_path / "missing.yaml")


def test_the_readers_name_the_file_and_keep_their_own_words(tmp_path):
    (tmp_path / "a.yaml").write_text("a: *nowhere\n")
    with pytest.raises(ValueError, match=r"cannot read assembly file .*a.yaml: invalid YAML"):
        load_assembly(tmp_path / "a.yaml")
    with pytest.raises(ValueError, match=r"a.yaml: invalid YAML"):
        load_block_calibration(tmp_path / "a.yaml")
    (tmp_path / "list.yaml").write_text("- a\n")
    with pytest.raises(ValueError, match=r"object 'a' is not in .*list.yaml; known: \[\]"):
        load_catalog_object("a", tmp_path / "list.yaml")


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300) | st.text(st.sampled_from("ab:-[]{}&*!|>'\"#\t\n ,?%@0.9e"), max_size=300))
def test_any_input_parses_or_is_refused_in_one_line(data):
    try:
        parse_yaml(data, "fuzzed", max_size=200)
    except YAMLInputError as error:
        assert str(error).startswith("fuzzed: ") and "\n" not in str(error) and len(str(error)) < 200
