"""`prepare_finger_search` reports each step as it starts and ends, so set-up (`python -m planner prepare-design`,
tens of seconds per field the first time) is never silent."""
import re

from planner.design import prepare_finger_search


def test_each_step_is_reported_with_its_counts_as_it_starts_and_ends():
    lines = []
    prepare_finger_search(configurations=((2, 0), (3, 1)), progress=lines.append)
    assert lines[0] == "[1/3] compiling the finger search kernels (numba; kept in its cache)"
    assert re.fullmatch(r"\[1/3\] kernels ready in \d+\.\d s", lines[1])
    assert lines[2] == ("[2/3] lookahead fields of 2 blocks, top 0 stiff (84/84 designs per position, base first): "
                        "building or loading")
    assert re.fullmatch(r"\[2/3\] lookahead fields of 2 blocks, top 0 stiff ready in \d+\.\d s", lines[3])
    assert lines[4].startswith("[3/3] lookahead fields of 3 blocks, top 1 stiff (42/84/84 designs per position")
    assert re.fullmatch(r"\[3/3\] lookahead fields of 3 blocks, top 1 stiff ready in \d+\.\d s", lines[5])
    assert len(lines) == 6
