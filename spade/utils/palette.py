"""SPADE's one palette: the colour of each thing a picture shows, the same in every picture and page.

Dataset previews (:mod:`spade.annotation.preview`), the MLflow prediction and progress pictures
(:mod:`spade.training.visualize`, :mod:`spade.tracking.progress_picture`), plan pictures
(:mod:`spade.deploy.plan_picture`), the run colours of the MLflow runs table
(:mod:`spade.tracking.predictors`) and the docs (``docs/reference/tracking.md``, "Colours") take their
colours from here. Defined once: a picture that needs a colour names the thing, not the colour.

* the robot (its start disc, its heading, the student's window around it): blue;
* the goal: red;
* the demonstration: green; the test set's plausible alternative demonstrations: a light green, dashed;
* the model's prediction (the path extracted from it, a plan): cyan, which neither the maps' greys nor the
  inferno heat map of path probabilities ever take; a low-confidence plan: amber;
* path probabilities: the inferno heat map (prediction pictures) or a magenta shade (plan pictures, over a
  white map);
* the reference predictors, one colour per kind: the untrained model grey, each classical baseline its own
  (straight line purple, Nav2-like shortest path orange, heading template brown); an expert olive.

The sketch app's front end (``spade/sketching/``) is meant to adopt the same names (its JavaScript cannot import
this module: :data:`CSS_VARIABLES` lists them as CSS custom properties).
"""

from __future__ import annotations

ROBOT = "#1f5fff"
GOAL = "#e8261f"
DEMONSTRATION = "#20b040"
ALTERNATIVE = "#a6e07a"
PREDICTION = "#00c8f0"
LOW_CONFIDENCE = "#ffb000"
PROBABILITY = "#e600c8"  # the shade of path probabilities over a white map (plan pictures)
PROBABILITY_CMAP = "inferno"  # the heat map of path probabilities over a dark map (prediction pictures)
WINDOW = ROBOT  # the student's window: it moves with the robot

# occupancy grey levels over which the colours above are drawn (unknown, free, occupied)
UNKNOWN_GREY = 150
FREE_GREY = 255
OCCUPIED_GREY = 0

UNTRAINED = "#8c8c8c"
EXPERT = "#a0a000"
BASELINES = {"straight": "#9467bd", "shortest": "#ff7f0e", "heading": "#8c564b"}
OTHER_BASELINE = "#e377c2"

LABELS = {"robot": ROBOT, "goal": GOAL, "demonstration": DEMONSTRATION, "alternative": ALTERNATIVE,
          "prediction": PREDICTION, "low-confidence": LOW_CONFIDENCE, "probability": PROBABILITY,
          "window": WINDOW, "untrained": UNTRAINED, "expert": EXPERT,
          **{f"baseline-{name}": colour for name, colour in BASELINES.items()}}
"""Every colour of the palette by the name a legend, a run's ``spade.predictor`` tag or a CSS variable uses."""

CSS_VARIABLES = "\n".join(f"  --spade-{name}: {colour};" for name, colour in LABELS.items())
"""The palette as CSS custom properties (``--spade-robot: #1f5fff;`` ...), for web front ends."""


def rgb(colour: str) -> tuple[int, int, int]:
    """``"#1f5fff"`` -> ``(31, 95, 255)``."""
    value = colour.lstrip("#")
    if len(value) != 6:
        raise ValueError(f"{colour!r}: not a #rrggbb colour")
    return int(value[0:2], 16), int(value[2:4], 16), int(value[4:6], 16)


def predictor_colour(predictor: str | None) -> str:
    """The colour of a predictor kind in run charts: ``student`` (the model itself, any role other than expert)
    cyan, ``expert`` olive, ``untrained`` grey, ``baseline-<name>`` its baseline's."""
    name = str(predictor or "")
    if name == "untrained":
        return UNTRAINED
    if name == "expert":
        return EXPERT
    if name.startswith("baseline-"):
        return BASELINES.get(name[len("baseline-"):], OTHER_BASELINE)
    return PREDICTION
