"""Compare the sample's answers from the container stack with the CLI's local run (issue 29).

    python .ci/containers/compare_answers.py LOCAL_OUT FETCHED_OUT

LOCAL_OUT is `bfields run samples/tabletop --out LOCAL_OUT`; FETCHED_OUT is `bfields fetch JOB
--out FETCHED_OUT` of the same scene and tasks submitted to the stack. Passes (exit 0) when every
task's first answer is the same object (id and Gaussian count) in both, and the stack's answers
are right on exactly the tasks the README and `tests/core/cli/test_sample_answers.py` say (7 of
8). Also prints whether the whole ranked lists agree and the largest probability difference, to
show how close the two runs are beyond what is required.
"""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))  # the ground-truth check lives with the tests, written once there

from bayesian_fields_core.results.reader import read_result  # noqa: E402
from tests.core.cli.test_sample_answers import RIGHT_TODAY, first_answers_right  # noqa: E402


def main(local_out: Path, fetched_out: Path) -> int:
    local, stack = read_result(local_out), read_result(fetched_out)
    right = first_answers_right(fetched_out)
    same_first = same_lists = True
    max_dp = 0.0
    print(f"{'task':<28} {'local 1st':>10} {'stack 1st':>10}  ranked lists  right")
    for task in local.tasks:
        mine, theirs = local.selections.get(task, []), stack.selections.get(task, [])
        first = [(o.object_id, o.num_gaussians) for o in mine[:1]]
        other = [(o.object_id, o.num_gaussians) for o in theirs[:1]]
        lists_equal = [o.object_id for o in mine] == [o.object_id for o in theirs]
        same_first &= first == other
        same_lists &= lists_equal
        for a, b in zip(mine, theirs, strict=False):
            max_dp = max(max_dp, abs(a.probability - b.probability))

        def name(answer: list[tuple[int, int]]) -> str:
            return f"{answer[0][0]} ({answer[0][1]})" if answer else "not found"

        print(f"{task:<28} {name(first):>10} {name(other):>10}  "
              f"{'same' if lists_equal else 'differ':<12}  {right.get(task)}")  # fmt: skip
    count = sum(right.values())
    print(f"first answers {'identical' if same_first else 'DIFFER'}; ranked lists "
          f"{'identical' if same_lists else 'differ'}; largest probability difference {max_dp:.2e}; "
          f"{count} of {len(right)} first answers right (expected {len(RIGHT_TODAY)}: {sorted(RIGHT_TODAY)})")  # fmt: skip
    ok = same_first and {t for t, r in right.items() if r} == RIGHT_TODAY
    return 0 if ok else 1


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    sys.exit(main(Path(sys.argv[1]), Path(sys.argv[2])))
