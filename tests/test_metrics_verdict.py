"""The verdict of a test names its figure and judges the model against every baseline."""

from __future__ import annotations

from spade.tracking.summary import evaluation_summary, learning_verdict
from spade.metrics.verdict import DECIDING_FIGURE, verdict_lines, verdicts


def metrics(**over: float) -> dict[str, float]:
    out = {
        "test/failure_rate": 0.0, "test/ape_cm": 11.25,
        "test/planner/ape_cm": 4.0, "test/planner/over_20cm_rate": 0.02,
        "test/baseline/straight/planner/ape_cm": 12.0, "test/baseline/straight/planner/over_20cm_rate": 0.20,
        "test/baseline/shortest/planner/ape_cm": 3.5, "test/baseline/shortest/planner/over_20cm_rate": 0.05,
        "test/baseline/heading/planner/ape_cm": 5.0, "test/baseline/heading/planner/over_20cm_rate": 0.01,
    }
    out.update(over)
    return out


def test_each_baseline_gets_its_outcome_by_the_planners_ape_and_tail() -> None:
    found = {v.baseline: v.outcome for v in verdicts(metrics())}
    # straight: lower APE, shorter tail; shortest: higher APE, shorter tail of the student -> mixed;
    # heading: lower APE but a longer tail -> mixed
    assert found == {"straight": "beats", "shortest": "mixed against", "heading": "mixed against"}
    worse = metrics(**{"test/planner/over_20cm_rate": 0.3})
    assert {v.baseline: v.outcome for v in verdicts(worse)}["shortest"] == "loses to"


def test_the_lines_name_the_deciding_figure_and_the_floor() -> None:
    m = metrics(**{"test/floor_cm": 3.24, "test/planner/ape_over_floor": 1.26,
                   "test/planner/plausibility_cm": 2.18, "test/baseline/straight/planner/plausibility_cm": 9.0,
                   "test/planner/commit_rate": 0.4, "test/baseline/straight/planner/commit_rate": 0.0})
    lines = verdict_lines(m, model="the student")
    assert DECIDING_FIGURE in lines[0]
    assert "3.24 cm" in lines[1] and "1.26x" in lines[1]
    straight = next(line for line in lines if "straight line" in line)
    assert "beats" in straight and "4.00 vs 12.00 cm" in straight and ">20 cm 2 % vs 20 %" in straight
    assert "plausibility 2.18 vs 9.00 cm" in straight and "commits 40 % vs 0 %" in straight
    assert len([line for line in lines if "the student" in line and " the " in line]) >= 3  # one per baseline


def test_lower_ape_but_less_plausible_is_said_in_words() -> None:
    m = metrics(**{"test/planner/plausibility_cm": 3.0, "test/baseline/straight/planner/plausibility_cm": 2.0})
    straight = next(v for v in verdicts(m) if v.baseline == "straight")
    assert "farther from any path an operator drew" in straight.sentence()


def test_the_summary_says_when_the_student_loses_and_when_it_learned_nothing() -> None:
    lost = learning_verdict(metrics(**{"test/planner/ape_cm": 20.0, "test/planner/over_20cm_rate": 0.5}))
    assert any("loses to the straight line" in line for line in lost)
    assert any("learns nothing" in line for line in lost)
    nothing = learning_verdict(metrics(**{"test/failure_rate": 1.0}))
    # one verdict (wrapped within the console's 120 columns)
    assert sum(line.startswith("  verdict") for line in nothing) == 1 and "no path" in nothing[0]
    assert learning_verdict({}) == []
    # an expert's test (it measures its samples' spread) is the expert's verdict, not a student's
    expert = learning_verdict(metrics(**{"test/planner/spread_cm": 2.0}))
    assert any(line.startswith("  verdict          : the expert beats") for line in expert)
    assert not any("the student" in line for line in expert)


def test_evaluate_ends_with_the_same_verdict() -> None:
    from omegaconf import OmegaConf

    text = evaluation_summary(OmegaConf.create({"ckpt_path": "student.ckpt"}),
                              metrics(**{"test/floor_cm": 3.0, "test/planner/ape_over_floor": 1.3}))
    assert "student.ckpt" in text and "floor" in text and "deciding figure" in text
    assert "baseline straight" in text or "straight" in text
