"""The commands and snippets of README.md and docs/*.md run as written, so a renamed parameter, option, module or
file breaks a test rather than a user.

Every fenced block is read. Shell lines: a module or script must exist and its command line must parse (the
program's own argparse parser, stopped right after parsing, in this process); node parameters given with
``-p name:=value``, ``--params-file`` or the launcher's ``--params`` must be declared by the node's schema
(softblock_ros/parameters.py) with a valid value; ``ros2 run`` names a console script, ``ros2 launch`` a launch
file, ``make`` a target, pytest a test path. A launcher line and a ``run_sequence`` line in one block must fit
together (the driver has every channel the sequence drives, the arm runs if it moves). A render line followed by
an estimate line must hand over the ``--base`` the render prints (the render runs). YAML blocks validate against
their schema (node parameters, a sequence, a block calibration); a block that starts with ``# name.yaml`` is the
file the page's commands call ``name.yaml``. Python blocks: imports run and every call of an imported name
binds to its signature; the snippets listed in RUN also run. Inline ``key: value`` lists of node parameters are
parameters of that node. No ROS process is started.
"""
from __future__ import annotations

import argparse
import ast
import contextlib
import inspect
import io
import os
import re
import runpy
import shlex
import subprocess
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import pytest
import yaml
from ros_domains import wrapper_domain
from softblock_config import config_file

from planner.assembly import load_assembly
from planner.block_calibration import parse_block_calibration
from sequencing.schema import Limits, load_sequence, parse_sequence
from softblock_ros.parameters import NODE_SCHEMAS, node_schema
from softblock_ros.stack import load_stack

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PACKAGE = ROOT / "ros_ws" / "src" / "softblock_ros"
STACK = load_stack()
NODE_OF_MODULE = {spec.module: spec.name for spec in STACK.nodes if not spec.arguments}
NODE_OF_EXECUTABLE = {spec.executable: spec.name for spec in STACK.nodes if not spec.arguments}
# Programs outside this repository (and shell built-ins) a page may show; their lines are not checked.
EXTERNAL = {"source", "cd", "export", "pip", "colcon", "for", "do", "done", "mcap", "usermod", "groups", "newgrp",
            "udevadm", "ls", "id", "dmesg", "sudo", "echo", "cat", "groupadd", "printf", "tee", "ulimit", "systemctl",
            "apt"}
EXTERNAL_ROS2 = {"bag", "security", "param", "topic", "node", "action", "service", "doctor"}
VENV_PYTHON = ".venv/bin/python"  # the environment's interpreter, for the core without the colcon build
# Words a page writes for a value the reader chooses, and a value of the right type to parse in their place.
PLACEHOLDER_VALUES = {"X": "0.07", "Y": "0.005", "ANGLE": "1.5708", "S": "1.0", "M": "0.0", "CH=V": "front=0"}
# Python blocks that run as written (key: the page and the block's first line); the others are checked
# statically. The value names the working directory: the repository, or a folder holding a recording.
RUN = {("docs/block_model.md", "from planner.block_model import BlockDesigns, BlockModel, Fidelity"): "root",
       ("docs/kinematics.md", "from planner.kinematics import ("): "root",
       ("docs/kinematics.md", "from planner.contours import load_mask, clean_mask, extract_contours, "
                              "load_catalog_object, ObjectContours"): "root",
       ("docs/hv_driver.md", "from hv_driver import ChannelConfig, HvSupply, LimitError"): "root",
       ("docs/recording.md", "from recording.analysis import analyze"): "recording"}


@dataclass(frozen=True)
class Block:
    page: str      # relative to the repository
    line: int      # of the opening fence
    language: str
    text: str

    @property
    def id(self) -> str:
        return f"{self.page}:{self.line}"


def blocks() -> list[Block]:
    found = []
    for path in PAGES:
        text = path.read_text()
        for match in re.finditer(r"^```(\w*)\n(.*?)^```", text, re.S | re.M):
            found.append(Block(str(path.relative_to(ROOT)), text[:match.start()].count("\n") + 1, match.group(1),
                               match.group(2)))
    return found


BLOCKS = blocks()
SHELL = [b for b in BLOCKS if b.language in ("bash", "sh", "")]
YAML = [b for b in BLOCKS if b.language == "yaml"]
PYTHON = [b for b in BLOCKS if b.language == "python"]


def named_files(page: str) -> dict[str, str]:
    """The YAML blocks of ``page`` that start with ``# name.yaml``: name -> text."""
    return {m.group(1): b.text for b in YAML if b.page == page and (m := re.match(r"# (\S+\.yaml)\n", b.text))}


# ----------------------------------------------------------------------------------------------- shell lines
def command_lines(block: Block) -> list[list[str]]:
    """The block's commands as argument lists: continuations joined, comments, prompts and output dropped,
    ``a && b`` split, environment assignments and scripts/with_env.sh taken off the front."""
    return [words for _, words in typed_commands(block)]


def typed_commands(block: Block) -> list[tuple[list[str], list[str]]]:
    """The block's commands as (what stands before the program: environment assignments, scripts/with_env.sh,
    sudo; the program's argument list)."""
    joined = re.sub(r"\\\n\s*|\n\s+(?=\[)", " ", block.text)  # a usage line goes on with an indented [option]
    commands = []
    for line in joined.splitlines():
        if not block.language and not (line.split() and is_command(line.split()[0])):
            continue  # an untyped block also shows output and what is typed into a program
        words, parts = shlex.split(line, comments=True), [[]]
        for word in words:  # `a && b` and `a; b` are two commands
            if word == "&&":
                parts.append([])
            else:
                parts[-1].append(word.removesuffix(";"))
                if word.endswith(";"):
                    parts.append([])
        for part in parts:
            prefix = []
            while part and (re.fullmatch(r"[A-Z_]+=\S*", part[0]) or part[0] in ("scripts/with_env.sh", "sudo")):
                prefix, part = [*prefix, part[0]], part[1:]
            if part:
                commands.append((prefix, part))
    return commands


def is_command(word: str) -> bool:
    return (word in EXTERNAL or word in ("python", "python3", "ros2", "make", VENV_PYTHON)
            or word.startswith(("ros_ws/", "benchmarks/", "scripts/")))


class Parsed(Exception):
    """Raised in place of running a program once its parser has accepted the command line."""

    def __init__(self, parser, namespace):
        super().__init__("parsed")
        self.parser, self.namespace = parser, namespace


@contextlib.contextmanager
def stop_after_parsing(parse: bool = True):
    """A program stops with Parsed once its parser has parsed (``parse``) or, else, as it starts to."""
    original = argparse.ArgumentParser.parse_args

    def parse_args(self, args=None, namespace=None):
        raise Parsed(self, original(self, args, namespace) if parse else None)

    argparse.ArgumentParser.parse_args = parse_args
    try:
        yield
    finally:
        argparse.ArgumentParser.parse_args = original


def parse_program(run, argv: list[str], where: str) -> Parsed:
    """Run ``run()`` with ``sys.argv = argv`` until its argparse parser has parsed; fail with its error otherwise."""
    saved, stderr = sys.argv, io.StringIO()
    sys.argv = argv
    try:
        with stop_after_parsing(), contextlib.redirect_stderr(stderr):
            run()
    except Parsed as parsed:
        return parsed
    except SystemExit as exit_:
        pytest.fail(f"{where}: {' '.join(argv)!r} does not parse (exit {exit_.code}): {stderr.getvalue().strip()}")
    finally:
        sys.argv = saved
    pytest.fail(f"{where}: {' '.join(argv)!r} ran without parsing a command line")


def synopsis(words: list[str]) -> tuple[list[str], list[list[str]]]:
    """A usage line (``[--opt V]`` optional, ``<name>`` a placeholder, ``a|b`` choices) -> the command line without
    its optional groups, and the groups' words."""
    text = " ".join(words)
    groups = [group.split() for group in re.findall(r"\[([^\[\]]*)\]", text)]
    bare = re.sub(r"\s*\[[^\[\]]*\]", "", text)
    return [re.sub(r"<([^>]+)>", r"\1", word) for word in bare.split()], groups


def known_options(parser: argparse.ArgumentParser, words: list[str]) -> set[str]:
    """Option strings of the (sub)parser that ``words`` reach."""
    options = set()
    for action in parser._actions:  # argparse offers no public walk of its actions
        options |= set(action.option_strings)
        if isinstance(action, argparse._SubParsersAction):
            for word in words:
                if word in action.choices:
                    return options | known_options(action.choices[word], words)
    return options


def params_file(path: str, block: Block) -> dict:
    """The parameter file ``path`` as a page uses it: one of the repository's, or the page's own named block."""
    path = path.replace("/path/to/softblock/", "")
    if path in named_files(block.page):
        return yaml.safe_load(named_files(block.page)[path])
    assert (ROOT / path).is_file(), f"{block.id}: parameter file {path} does not exist (nor a `# {path}` block)"
    return yaml.safe_load((ROOT / path).read_text())


def check_sections(document: dict, where: str, nodes=None) -> None:
    """Every node section of a parameter file: the node exists and declares each key, and each value is valid."""
    for node, body in document.items():
        values = body["ros__parameters"]
        assert node in NODE_SCHEMAS, f"{where}: section {node!r} is no node of the stack ({', '.join(NODE_SCHEMAS)})"
        assert nodes is None or node in nodes, f"{where}: section {node!r} for a node this command does not start"
        schema = {param.name: param for param in node_schema(node)}
        unknown = sorted(set(values) - set(schema))
        assert not unknown, f"{where}: {unknown} not parameters of {node} (known: {', '.join(sorted(schema))})"
        for name, value in values.items():
            schema[name].check(value)


def check_ros_arguments(node: str, arguments: list[str], block: Block) -> None:
    assert not arguments or arguments[0] == "--ros-args", f"{block.id}: {node} takes only ROS arguments: {arguments}"
    schema = {param.name: param for param in node_schema(node)}
    words = iter(arguments[1:])
    for word in words:
        if word == "-p":
            name, _, value = next(words).partition(":=")
            assert name in schema, f"{block.id}: -p {name}: not a parameter of {node} (known: {', '.join(schema)})"
            schema[name].check(yaml.safe_load(value))
        elif word == "--params-file":
            check_sections(params_file(next(words), block), block.id, nodes=None)
        elif word in ("-r", "--remap", "--enclave", "--log-level"):
            next(words)
        else:
            pytest.fail(f"{block.id}: unexpected ROS argument {word!r} for {node}")


def check_python_module(module: str, arguments: list[str], block: Block) -> Parsed | None:
    if module == "pytest":
        paths = [word.split("::")[0] for word in arguments if word.startswith("tests")]
        missing = [path for path in paths if not (ROOT / path).exists()]
        assert not missing, f"{block.id}: test paths {missing} do not exist"
        return None
    if module in NODE_OF_MODULE:
        check_ros_arguments(NODE_OF_MODULE[module], arguments, block)
        return None
    return parse_program(lambda: runpy.run_module(module, run_name="__main__", alter_sys=True),
                         [module, *arguments], block.id)


def check_console_script(name: str, arguments: list[str], block: Block) -> Parsed | None:
    scripts = console_scripts()
    assert name in scripts, f"{block.id}: no console script {name!r} in softblock_ros (setup.py)"
    if name in NODE_OF_EXECUTABLE:
        check_ros_arguments(NODE_OF_EXECUTABLE[name], arguments, block)
        return None
    module, function = scripts[name].split(":")
    return parse_program(getattr(__import__(module, fromlist=[function]), function), [name, *arguments], block.id)


def console_scripts() -> dict[str, str]:
    tree = ast.parse((PACKAGE / "setup.py").read_text())
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "setup")
    entry_points = ast.literal_eval(next(k.value for k in call.keywords if k.arg == "entry_points"))
    return dict(line.replace(" ", "").split("=") for line in entry_points["console_scripts"])



def run_script(script: Path) -> None:
    """``python script.py`` in this process: as Python does, the script's folder comes first on sys.path (a
    benchmark imports its sibling scripts)."""
    sys.path.insert(0, str(script.parent))
    try:
        runpy.run_path(str(script), run_name="__main__")
    finally:
        sys.path.remove(str(script.parent))

def check_command(words: list[str], block: Block) -> Parsed | None:
    """Check one command; the parsed command line when the program's parser ran."""
    words = [PLACEHOLDER_VALUES.get(word, word) for word in words]
    for word in words:  # a path into the repository exists (outputs excepted)
        if re.match(r"(config|docs|tests|benchmarks|scripts)/", word) and not word.startswith("docs/figures/"):
            assert (ROOT / word.split("::")[0]).exists(), f"{block.id}: {word} does not exist"
    head, rest = words[0], words[1:]
    head = "python" if head == VENV_PYTHON else head
    if head in EXTERNAL or (head == "ros2" and rest[0] in EXTERNAL_ROS2):
        return None
    if head in ("python", "python3") and rest[:2] == ["-m", "venv"]:
        return None
    if head == "make":
        targets = re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), re.M)
        assert set(rest) <= set(targets), f"{block.id}: make {rest}: targets are {targets}"
        return None
    if head in ("python", "python3") and rest[0] == "-m":
        return check_python_module(rest[1], rest[2:], block)
    if head in ("python", "python3"):
        script = ROOT / rest[0]
        assert script.is_file(), f"{block.id}: {rest[0]} does not exist"
        if "argparse" not in script.read_text():  # a script without options: running it would do its work
            assert not rest[1:], f"{block.id}: {rest[0]} takes no arguments: {rest[1:]}"
            return None
        return parse_program(lambda: run_script(script), rest, block.id)
    if head == "ros2" and rest[0] == "run":
        assert rest[1] == "softblock_ros", f"{block.id}: ros2 run of another package: {words}"
        return check_console_script(rest[2], rest[3:], block)
    if head == "ros2" and rest[0] == "launch":
        assert rest[1] == "softblock_ros" and (PACKAGE / "launch" / rest[2]).is_file(), f"{block.id}: {words}"
        return None
    if head.startswith("ros_ws/install/softblock_ros/lib/softblock_ros/"):
        return check_console_script(Path(head).name, rest, block)
    pytest.fail(f"{block.id}: no rule for {' '.join(words)!r}; add the program to EXTERNAL if it is not ours")


COMMANDS = [(block, words) for block in SHELL for words in command_lines(block)]


@pytest.mark.parametrize("block, words", COMMANDS, ids=[f"{b.id}:{w[0]} {' '.join(w[1:3])}" for b, w in COMMANDS])
def test_each_documented_command_parses_with_the_names_it_uses(block, words):
    if words[0] not in EXTERNAL and any("[" in word or re.fullmatch(r"<[^>]+>", word) for word in words):
        bare, groups = synopsis(words)
        parsed = check_command(bare, block)
        assert parsed is not None, f"{block.id}: a usage line of a program without a parser: {words}"
        options = known_options(parsed.parser, bare)
        unknown = [word for group in groups for word in group if word.startswith("--") and word not in options]
        assert not unknown, f"{block.id}: options {unknown} are not options of {' '.join(bare[:3])}"
        return
    parsed = check_command(words, block)
    if parsed is not None and words[-1:] != ["--help"] and "launcher" in " ".join(words[:3]):
        check_launch(parsed.namespace, block)


def check_launch(args, block: Block) -> None:
    nodes = args.nodes.split(",") if args.nodes else list(STACK.names)
    unknown = sorted(set(nodes) - set(STACK.names))
    assert not unknown, f"{block.id}: --nodes {unknown} are not nodes of config/stack.yaml ({', '.join(STACK.names)})"
    if args.params:
        check_sections(params_file(args.params, block), f"{block.id} --params {args.params}")


# ------------------------------------------------------------------------------ what commands hand each other
def effective_parameters(node: str, params: str | None, block: Block) -> dict:
    """The parameters ``node`` starts with from the launcher: its schema's defaults, its stack files, --params."""
    values = {param.name: param.default for param in node_schema(node)}
    documents = [yaml.safe_load(path.read_text()) for path in STACK.node(node).parameters]
    if params:
        documents.append(params_file(params, block))
    for document in documents:
        values.update((document or {}).get(node, {}).get("ros__parameters", {}))
    return values


def launcher_and_sequence(block: Block):
    commands = command_lines(block)
    launches = [w for w in commands if "softblock_ros.launcher" in w]
    sequences = [w for w in commands if "softblock_ros.run_sequence" in w]
    return (launches[0], sequences[0]) if launches and sequences else None


PAIRS = [(block, pair) for block in SHELL if (pair := launcher_and_sequence(block))]


@pytest.mark.parametrize("block, pair", PAIRS, ids=[b.id for b, _ in PAIRS])
def test_a_documented_sequence_runs_on_the_stack_documented_with_it(block, pair):
    from softblock_ros import launcher, run_sequence
    launch, run = pair
    args = parse_program(launcher.main, launch[launch.index("softblock_ros.launcher"):], block.id).namespace
    name = parse_program(run_sequence.main, run[run.index("softblock_ros.run_sequence"):], block.id).namespace.sequence
    nodes = args.nodes.split(",") if args.nodes else list(STACK.names)
    sequencer = effective_parameters("sequencer", args.params, block)
    limits = Limits(voltage_ceiling_v=sequencer["voltage_ceiling_v"],
                    max_pulse_frequency_hz=sequencer["max_pulse_frequency_hz"])
    sequence = load_sequence(name, config_file("sequences"), limits)
    driver = effective_parameters("hv_driver", args.params, block)
    missing = sorted(set(sequence.channels) - set(driver["channel_names"]))
    assert not missing, (f"{block.id}: {name} drives {missing}, which the driver of this stack lacks "
                         f"(channel_names {driver['channel_names']}): the sequencer would e-stop it")
    assert {"hv_driver", "sequencer"} <= set(nodes), f"{block.id}: {name} needs hv_driver and sequencer: {nodes}"
    if "move_arm:" in config_file(f"sequences/{name}.yaml").read_text():
        assert "sim_arm" in nodes, f"{block.id}: {name} moves the arm, and the stack has no sim_arm: {nodes}"


# ------------------------------------------------------------------------ terminals: what runs beside what
# A comment line naming a terminal or a machine starts the commands typed into the next one.
TERMINAL_MARK = re.compile(r"^#.*\b(?:terminal|machine|PC|workstation)\b.*$", re.M | re.I)
MACHINE_MARK = re.compile(r"\b(?:machine|PC|workstation)\b", re.I)


def terminals(block: Block) -> list[list[tuple[list[str], list[str]]]]:
    """The block's typed commands (typed_commands), by the terminal or machine each is typed into."""
    return [commands for part in TERMINAL_MARK.split(block.text) if (commands := typed_commands(replace(block, text=part)))]


def starts_stack(words: list[str]) -> bool:
    """A command that runs nodes in the foreground until Ctrl-C."""
    text = " ".join(words)
    return ("softblock_ros.launcher" in text or words[:2] == ["ros2", "launch"]
            or (words[:2] == ["python", "-m"] and words[2] in NODE_OF_MODULE)
            or (words[:2] == ["ros2", "run"] and words[3:4] and words[3] in {*NODE_OF_EXECUTABLE, "launcher"}))


def needs_stack(words: list[str]) -> bool:
    """A command that talks to nodes running elsewhere (and fails or waits without them)."""
    program = words[2] if words[:2] in (["python", "-m"], ["python3", "-m"]) else " ".join(words[:4])
    return (program in ("softblock_ros.run_sequence", "ros2 run softblock_ros run_sequence")
            or (program in ("softblock_ros.hv_console", "ros2 run softblock_ros hv_console") and "--probe" not in words)
            or (words[0] == "ros2" and words[1] in ("topic", "service", "action", "node", "param")))


def ros_domain(prefix: list[str], words: list[str], exported: str | None) -> tuple[str, bool]:
    """The ROS domain a command joins, and whether the page chose it (rather than a default): the launcher's
    --domain-id, else ROS_DOMAIN_ID given before the command or exported in its terminal, else the default of
    scripts/with_env.sh (asked of the wrapper itself, in a process of its own as each command runs) or of ROS 2."""
    if "--domain-id" in words:
        return words[words.index("--domain-id") + 1], True
    given = [word.partition("=")[2] for word in prefix if word.startswith("ROS_DOMAIN_ID=")]
    chosen = given[-1] if given else exported
    if "scripts/with_env.sh" not in prefix:
        return chosen or "0", chosen is not None
    return str(wrapper_domain(chosen)), chosen is not None


def graph_domains(block: Block) -> list[tuple[int, str, str, bool]]:
    """(terminal, command, domain, chosen by the page) of each command of the block that runs or needs nodes."""
    found = []
    for terminal, commands in enumerate(terminals(block)):
        exported = None
        for prefix, words in commands:
            if words[0] == "export":
                exported = next((w.partition("=")[2] for w in words if w.startswith("ROS_DOMAIN_ID=")), exported)
            elif starts_stack(words) or needs_stack(words):
                found.append((terminal, " ".join(words[:4]), *ros_domain(prefix, words, exported)))
    return found


SEVERAL_TERMINALS = [b for b in SHELL if len({terminal for terminal, *_ in graph_domains(b)}) >= 2]
STACK_AND_CLIENT = [b for b in SHELL if any(map(starts_stack, command_lines(b))) and any(map(needs_stack, command_lines(b)))]


@pytest.mark.parametrize("block", SEVERAL_TERMINALS, ids=[b.id for b in SEVERAL_TERMINALS])
def test_the_terminals_of_a_block_meet_in_one_ros_domain(block):
    """Typed as written, each terminal's commands join the same ROS domain (a per-process default of the
    wrapper left run_sequence in one terminal without the sequencer started in another: exit 3)."""
    commands = graph_domains(block)
    domains = {domain for _, _, domain, _ in commands}
    assert len(domains) == 1, f"{block.id}: the terminals' commands run in different ROS domains: " + "; ".join(
        f"terminal {terminal + 1}: {command!r} in domain {domain}" for terminal, command, domain, _ in commands)
    if MACHINE_MARK.search(" ".join(TERMINAL_MARK.findall(block.text))):  # each machine's defaults are its own
        unchosen = [command for _, command, _, chosen in commands if not chosen]
        assert not unchosen, f"{block.id}: on two machines the domain must be given, not a default: {unchosen}"


@pytest.mark.parametrize("block", STACK_AND_CLIENT, ids=[b.id for b in STACK_AND_CLIENT])
def test_a_client_of_the_stack_is_typed_into_another_terminal_than_the_stack(block):
    """The launcher holds its terminal until Ctrl-C: a client typed after it into the same terminal never runs
    while the stack does."""
    for commands in terminals(block):
        stack = next((i for i, (_, words) in enumerate(commands) if starts_stack(words)), len(commands))
        late = [" ".join(words[:4]) for _, words in commands[stack + 1:] if needs_stack(words)]
        assert not late, (f"{block.id}: {late} typed after {' '.join(commands[stack][1][:4])!r} into one terminal; "
                          "mark the second terminal (`# second terminal:`)")


RENDER_PAIRS = [(block, render, estimate) for block in SHELL
                for render, estimate in zip(command_lines(block), command_lines(block)[1:])
                if render[1:4] == ["-m", "estimation", "render"] and estimate[1:4] == ["-m", "estimation", "estimate"]]


@pytest.mark.parametrize("block, render, estimate", RENDER_PAIRS, ids=[b.id for b, _, _ in RENDER_PAIRS])
def test_an_estimate_takes_the_base_its_render_printed(block, render, estimate, tmp_path):
    command = [str(ROOT / word) if "/" in word and (ROOT / word).exists() else word for word in render[1:]]
    result = subprocess.run([sys.executable, *command], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                            env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert result.returncode == 0, result.stderr
    printed = re.search(r"--base (\S+) (\S+) (\S+)", result.stdout)
    given = estimate[estimate.index("--base") + 1:][:3]
    assert printed and [float(v) for v in printed.groups()] == [float(v) for v in given], (
        f"{block.id}: render prints {printed and printed.group(0)!r}, the estimate line gives --base {' '.join(given)}")


def files_given_as(options: tuple[str, ...]) -> dict[str, set[str]]:
    """File name -> the pages whose commands give it after one of ``options``."""
    found: dict[str, set[str]] = {}
    for block in SHELL:
        for words in command_lines(block):
            for option, value in zip(words, words[1:]):
                if option in options:
                    found.setdefault(Path(value).name, set()).add(block.page)
    return found


def test_no_file_name_is_a_parameter_file_on_one_page_and_an_assembly_on_another():
    """A lab that follows two pages keeps one file of each name (the quick start's driver parameters and the
    estimation's assembly were both rig.yaml)."""
    parameters = files_given_as(("--params", "--params-file"))
    assemblies = files_given_as(("--assembly",))
    both = {name: sorted(parameters[name] | assemblies[name]) for name in set(parameters) & set(assemblies)}
    assert not both, f"parameter file and assembly under one name: {both}"


# ------------------------------------------------------------------------------------------------ YAML blocks
@pytest.mark.parametrize("block", YAML, ids=[b.id for b in YAML])
def test_each_yaml_block_is_valid_against_its_schema(block, tmp_path):
    document = yaml.safe_load(block.text)
    if all(isinstance(body, dict) and "ros__parameters" in body for body in document.values()):
        check_sections(document, block.id)
    elif "steps" in document:
        parse_sequence(document, source=block.id)
    elif set(document) == {"blocks"}:
        parse_block_calibration(document, block.id)
    else:
        pytest.fail(f"{block.id}: a YAML block of no known kind (node parameters, a sequence, a block calibration)")


# -------------------------------------------------------------------------- inline node parameter lists
PARAMETER_SPAN = re.compile(r"`([a-z][a-z0-9_]*): ([^`]+)`")
INLINE = [(str(path.relative_to(ROOT)), number, line) for path in PAGES
          for number, line in enumerate(path.read_text().splitlines(), start=1)
          if len(PARAMETER_SPAN.findall(line)) >= 2]


@pytest.mark.parametrize("page, number, line", INLINE, ids=[f"{p}:{n}" for p, n, _ in INLINE])
def test_an_inline_list_of_node_parameters_names_parameters_of_one_node(page, number, line):
    spans = PARAMETER_SPAN.findall(line)
    owners = [node for node in NODE_SCHEMAS if any(key in {p.name for p in node_schema(node)} for key, _ in spans)]
    if not owners:
        return  # not node parameters (e.g. sequence step fields)
    schema = {param.name: param for param in node_schema(owners[0])}
    for key, value in spans:
        assert key in schema, f"{page}:{number}: `{key}: ...` is not a parameter of {owners[0]}"
        if "..." not in value:
            schema[key].check(yaml.safe_load(value))


# ------------------------------------------------------------------------------------ inline subcommand lists
SUBCOMMAND_LIST = re.compile(r"`python -m ([\w.]+) \{([\w,]+)\}")
SUBCOMMAND_LISTS = [(str(path.relative_to(ROOT)), number, match.group(1), match.group(2).split(","))
                    for path in PAGES for number, line in enumerate(path.read_text().splitlines(), start=1)
                    for match in SUBCOMMAND_LIST.finditer(line)]


def subcommands(module: str) -> set[str]:
    """The subcommands of ``python -m module`` (its parser, taken as the program starts to parse)."""
    saved = sys.argv
    sys.argv = [module]
    try:
        with stop_after_parsing(parse=False):
            runpy.run_module(module, run_name="__main__", alter_sys=True)
    except Parsed as parsed:
        return {name for action in parsed.parser._actions if isinstance(action, argparse._SubParsersAction)
                for name in action.choices}
    finally:
        sys.argv = saved
    pytest.fail(f"python -m {module} built no parser")


@pytest.mark.parametrize("page, number, module, listed", SUBCOMMAND_LISTS,
                         ids=[f"{p}:{n}:{m}" for p, n, m, _ in SUBCOMMAND_LISTS])
def test_an_inline_list_of_subcommands_names_them_all(page, number, module, listed):
    assert set(listed) == subcommands(module), (
        f"{page}:{number}: `python -m {module} {{{','.join(listed)}}}`; its subcommands are "
        f"{{{','.join(sorted(subcommands(module)))}}}")


# ---------------------------------------------------------------------------------------------- Python blocks
def resolved_calls(tree: ast.Module, namespace: dict):
    """(text, object, positional count, keyword names) of every call whose callee is an imported name or an
    attribute chain on one (AttributeError for a chain that does not resolve)."""
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        chain, target = [], node.func
        while isinstance(target, ast.Attribute):
            chain.insert(0, target.attr)
            target = target.value
        if not isinstance(target, ast.Name) or target.id not in namespace:
            continue
        callee = namespace[target.id]
        for attribute in chain:
            callee = getattr(callee, attribute)
        yield ast.unparse(node.func), callee, len(node.args), [k.arg for k in node.keywords if k.arg]


@pytest.mark.parametrize("block", PYTHON, ids=[b.id for b in PYTHON])
def test_each_python_block_imports_and_calls_what_exists(block):
    tree = ast.parse(block.text)
    namespace: dict = {}
    imports = ast.Module([n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))], type_ignores=[])
    exec(compile(imports, block.id, "exec"), namespace)
    for text, callee, positional, keywords in resolved_calls(tree, namespace):
        if hasattr(callee, "get_fields_and_field_types"):  # a ROS message: keyword = field
            unknown = sorted(set(keywords) - set(callee.get_fields_and_field_types()))
            assert not unknown, f"{block.id}: {text}(...) has no field(s) {unknown}"
            continue
        try:
            signature = inspect.signature(callee)
        except (TypeError, ValueError):
            continue  # a builtin without a signature
        try:
            signature.bind_partial(*[None] * positional, **dict.fromkeys(keywords))
        except TypeError as error:
            pytest.fail(f"{block.id}: {text}(...) does not fit {text}{signature}: {error}")


def test_every_snippet_listed_to_run_is_on_its_page():
    present = {(b.page, b.text.splitlines()[0]) for b in PYTHON}
    assert set(RUN) <= present, f"listed in RUN but not found: {set(RUN) - present}"


@pytest.fixture
def gripper_recording(tmp_path):
    """grasp.mcap in a fresh folder: hv/state on the driver's channels and assembly/state of the shipped gripper."""
    sys.path.insert(0, str(ROOT / "tests" / "recording"))
    try:
        from recording_helpers import assembly_state, hv_state, stamp, write_recording
    finally:
        sys.path.remove(str(ROOT / "tests" / "recording"))
    channels = yaml.safe_load(config_file("hv_driver.yaml").read_text())["hv_driver"]["ros__parameters"]
    gripper = load_assembly(config_file("assemblies/gripper.yaml"))
    start, entries = 1_700_000_000_000_000_000, []
    for i in range(5):
        at = start + i * 100_000_000
        entries.append(("/hv/state", stamp(at, hv_state({name: 600.0 * i for name in channels["channel_names"]})), at))
        entries.append(("/assembly/state", stamp(at, assembly_state({chain.name: [0.5] * len(chain.blocks)
                                                                     for chain in gripper.chains})), at))
    write_recording(str(tmp_path / "grasp.mcap"), entries)
    return tmp_path


@pytest.mark.parametrize("key", RUN, ids=[f"{page}:{line[:40]}" for page, line in RUN])
def test_the_runnable_python_blocks_run_as_written(key, request, monkeypatch):
    (block,) = [b for b in PYTHON if (b.page, b.text.splitlines()[0]) == key]
    monkeypatch.chdir(ROOT if RUN[key] == "root" else request.getfixturevalue("gripper_recording"))
    with contextlib.redirect_stdout(io.StringIO()):
        exec(compile(block.text, block.id, "exec"), {"__name__": "__doc_snippet__"})



def test_a_python_command_runs_in_the_projects_environment():
    """Typed into a fresh terminal, `python -m planner ...` finds no planner: a command runs through
    scripts/with_env.sh, or (the core alone, without the colcon build) with the venv's own .venv/bin/python."""
    outside = [f"{block.id}: {' '.join(words)}" for block in SHELL for prefix, words in typed_commands(block)
               if words[0] in ("python", "python3") and words[1:3] != ["-m", "venv"]
               and "scripts/with_env.sh" not in prefix]
    assert not outside, "run outside the environment (prefix scripts/with_env.sh):\n" + "\n".join(outside)
