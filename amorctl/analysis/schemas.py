"""JSON Schemas (draft 2020-12) of ``amorctl pareto --json`` (and ``--coverage``) and ``evaluate --json``.

The same schemas are printed in docs/pareto.md and docs/evaluate.md (a test checks they agree)
and the test suite validates real command output against them with ``jsonschema``.
Numbers that can be undefined (a NaN mean, a tracking metric of an env without a reference) are
``null``.
"""

from __future__ import annotations

from typing import Any

_NUM_OR_NULL: dict[str, Any] = {"type": ["number", "null"]}
_MATRIX: dict[str, Any] = {"type": "array", "items": {"type": "array", "items": _NUM_OR_NULL}}
_VECTOR: dict[str, Any] = {"type": "array", "items": _NUM_OR_NULL}
_BOOLS: dict[str, Any] = {"type": "array", "items": {"type": "boolean"}}
_FRACTION_OR_NULL: dict[str, Any] = {"type": ["number", "null"], "minimum": 0, "maximum": 1}

_HYPERVOLUME: dict[str, Any] = {
    "type": "object",
    "required": [
        "value", "method", "ci_low", "ci_high", "confidence", "n_samples", "n_points", "reference_point",
    ],
    "properties": {
        "value": {"type": "number", "minimum": 0},
        "method": {"enum": ["exact", "monte_carlo"]},
        "ci_low": {"type": "number"},
        "ci_high": {"type": "number"},
        "confidence": {"type": "number", "exclusiveMinimum": 0, "maximum": 1},
        "n_samples": {"type": "integer", "minimum": 0},
        "n_points": {"type": "integer", "minimum": 0},
        "reference_point": {"type": "array", "items": {"type": "number"}},
    },
}  # fmt: skip

PARETO_JSON_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "$id": "https://amorctl.invalid/schemas/pareto.json",
    "title": "amorctl pareto --json (also pareto.json)",
    "type": "object",
    "required": [
        "run", "objectives", "weights", "sampling", "samples", "episodes", "episode_seconds",
        "reference_point_rule", "motions", "timing", "files",
    ],
    "properties": {
        "run": {"type": "string", "description": "the run directory"},
        "objectives": {"type": "array", "items": {"type": "string"}, "minItems": 1},
        "weights": {**_MATRIX, "description": "[K][m] the sampled weight vectors, rows on the simplex"},
        "sampling": {"type": "string", "description": "dirichlet(1) or simplex grid (N divisions)"},
        "samples": {"type": "integer", "minimum": 1, "description": "K"},
        "episodes": {"type": "integer", "minimum": 1, "description": "E episodes per weight vector"},
        "episode_seconds": {"type": "number", "description": "the episodes' time limit"},
        "reference_point_rule": {"type": "string"},
        "motions": {
            "type": "array",
            "minItems": 1,
            "items": {
                "type": "object",
                "required": [
                    "motion", "points", "points_std", "survival", "equal_weights_point", "non_dominated",
                    "pairwise_non_dominated", "non_dominated_fraction", "hypervolume", "expected_utility",
                    "sparsity", "survivors",
                ],
                "properties": {
                    "motion": {"type": "string", "description": "clip name, or 'all'"},
                    "points": {**_MATRIX, "description": "[K][m] mean unscaled returns over E episodes"},
                    "points_std": {**_MATRIX, "description": "[K][m] their standard deviation"},
                    "survival": {**_VECTOR, "description": "[K] fraction of episodes reaching the limit"},
                    "equal_weights_point": {**_VECTOR, "description": "[m] returns under w = 1/m"},
                    "non_dominated": {**_BOOLS, "description": "[K] non-dominated in all m objectives"},
                    "pairwise_non_dominated": {
                        "type": "object",
                        "description": "'a/b' -> [K] non-dominated in objectives a and b alone",
                        "additionalProperties": _BOOLS,
                    },
                    "non_dominated_fraction": {"type": "number", "minimum": 0, "maximum": 1},
                    "hypervolume": _HYPERVOLUME,
                    "expected_utility": {"type": "number"},
                    "sparsity": {"type": "number", "minimum": 0},
                    "survivors": {
                        "type": "object",
                        "description": "the front of the weight vectors with a surviving episode, each "
                        "point the mean over its surviving episodes; same reference point (null: none)",
                        "required": [
                            "count", "fallen", "points", "non_dominated", "non_dominated_fraction",
                            "hypervolume", "expected_utility", "sparsity",
                        ],
                        "properties": {
                            "count": {"type": "integer", "minimum": 0},
                            "fallen": {"type": "integer", "minimum": 0, "description": "all episodes fell"},
                            "points": {**_MATRIX, "description": "[K][m], rows of null where all fell"},
                            "non_dominated": {**_BOOLS, "description": "[K] among survivors"},
                            "non_dominated_fraction": {**_FRACTION_OR_NULL},
                            "hypervolume": {"oneOf": [{"type": "null"}, _HYPERVOLUME]},
                            "expected_utility": _NUM_OR_NULL,
                            "sparsity": {"type": ["number", "null"], "minimum": 0},
                        },
                    },
                },
            },
        },
        "timing": {
            "type": "object",
            "required": ["num_envs", "env_steps", "seconds"],
            "properties": {
                "num_envs": {"type": "integer", "minimum": 1},
                "env_steps": {"type": "integer", "minimum": 0},
                "seconds": {"type": "number", "minimum": 0},
            },
        },
        "files": {
            "type": "object",
            "description": "json, csv, png, svg -> path",
            "additionalProperties": {"type": "string"},
        },
    },
}  # fmt: skip

_METRICS: dict[str, Any] = {
    "type": "object",
    "required": [
        "episodes", "survival_rate", "episode_length_steps", "episode_length_s", "joint_mae_deg", "mpjpe_mm",
    ],
    "properties": {
        "episodes": {"type": "number", "minimum": 1},
        "survival_rate": {"type": "number", "minimum": 0, "maximum": 1},
        "episode_length_steps": {"type": "number", "minimum": 0},
        "episode_length_s": {"type": "number", "minimum": 0},
        "joint_mae_deg": {**_NUM_OR_NULL, "description": "mean |q - q_ref| over joints and steps, degrees"},
        "mpjpe_mm": {**_NUM_OR_NULL, "description": "mean end-effector position error, mm"},
    },
    "description": "plus joint_mae_deg/<up|lo|feet>, return/<objective>, return_std/<objective>",
    "additionalProperties": _NUM_OR_NULL,
}  # fmt: skip

EVALUATE_JSON_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "$id": "https://amorctl.invalid/schemas/evaluate.json",
    "title": "amorctl evaluate --json",
    "type": "object",
    "required": ["run", "objectives", "episodes", "motions", "settings", "sweep", "video"],
    "properties": {
        "run": {"type": "string"},
        "objectives": {"type": "array", "items": {"type": "string"}, "minItems": 1},
        "episodes": {"type": "integer", "minimum": 1},
        "motions": {"type": "array", "items": {"type": "string"}},
        "settings": {
            "type": "array",
            "items": {
                "type": "object",
                "required": ["label", "weights", "episodes", "metrics", "per_motion", "per_joint"],
                "properties": {
                    "label": {"type": "string", "description": "uniform | weights | schedule"},
                    "weights": {"type": "string"},
                    "episodes": {"type": "integer", "minimum": 1},
                    "metrics": _METRICS,
                    "per_motion": {"type": "object", "additionalProperties": _METRICS},
                    "per_joint": {
                        "type": "object",
                        "description": "joint name -> its error in degrees ({} without --per-joint)",
                        "additionalProperties": {
                            "type": "object",
                            "required": ["mae_deg", "bias_deg", "p95_deg"],
                            "properties": {
                                "mae_deg": {"type": "number", "minimum": 0},
                                "bias_deg": {"type": "number"},
                                "p95_deg": {"type": "number", "minimum": 0},
                            },
                            "additionalProperties": False,
                        },
                    },
                },
            },
        },
        "sweep": {
            "oneOf": [
                {"type": "null"},
                {
                    "type": "object",
                    "required": [
                        "objective", "levels", "returns", "mean", "survival", "spearman_rho", "spearman_p",
                        "action_rate", "joint_vel_rms", "step_pairs", "action_rate_falls",
                        "joint_vel_rms_falls", "figure",
                    ],
                    "properties": {
                        "objective": {"type": "string"},
                        "levels": {**_VECTOR, "minItems": 3},
                        "returns": {**_MATRIX, "description": "[L][E] unweighted cumulative reward"},
                        "mean": _VECTOR,
                        "survival": _VECTOR,
                        "spearman_rho": _NUM_OR_NULL,
                        "spearman_p": _NUM_OR_NULL,
                        "action_rate": {
                            "type": "array",
                            "items": _NUM_OR_NULL,
                            "description": "[L] mean per step of ||q*_t - q*_(t-1)||², the PD targets",
                        },
                        "joint_vel_rms": {
                            "oneOf": [{"type": "null"}, {"type": "array", "items": _NUM_OR_NULL}],
                            "description": "[L] joint-velocity RMS, rad/s (null: the env has no joints)",
                        },
                        "step_pairs": {"type": "array", "items": {"type": "integer", "minimum": 0}},
                        "action_rate_falls": {"type": "boolean"},
                        "joint_vel_rms_falls": {"oneOf": [{"type": "null"}, {"type": "boolean"}]},
                        "figure": {"type": "string"},
                    },
                },
            ]
        },
        "video": {
            "oneOf": [
                {"type": "null"},
                {
                    "type": "object",
                    "required": ["path", "frames", "width", "height", "fps", "gl_backend"],
                    "properties": {
                        "path": {"type": "string"},
                        "frames": {"type": "integer", "minimum": 1},
                        "width": {"type": "integer"},
                        "height": {"type": "integer"},
                        "fps": {"type": "number"},
                        "gl_backend": {"type": "string"},
                    },
                },
            ]
        },
    },
}  # fmt: skip

COVERAGE_JSON_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "$id": "https://amorctl.invalid/schemas/coverage.json",
    "title": "amorctl pareto --coverage --json (also coverage.json)",
    "type": "object",
    "required": [
        "run", "objectives", "gamma", "samples", "episode_seconds", "regions", "training_logged", "overall",
        "per_sample", "timing", "files",
    ],
    "properties": {
        "run": {"type": "string"},
        "objectives": {"type": "array", "items": {"type": "string"}, "minItems": 1},
        "gamma": {"type": "number", "description": "the run's discount, applied to the achieved return"},
        "samples": {"type": "integer", "minimum": 1, "description": "K weight vectors, one episode each"},
        "episode_seconds": {"type": "number"},
        "regions": {
            "type": "array",
            "description": "4 m regions: dominant objective x bin of its weight",
            "items": {
                "type": "object",
                "required": [
                    "region", "objective", "bin", "feasible", "samples", "predicted", "achieved", "gap",
                    "relative_gap", "survival", "training_episodes", "training_share",
                ],
                "properties": {
                    "region": {"type": "string", "description": "<objective>:<lo>-<hi>"},
                    "objective": {"type": "string"},
                    "bin": {"type": "string"},
                    "feasible": {"type": "boolean", "description": "false: the bin lies below 1/m"},
                    "samples": {"type": "integer", "minimum": 0},
                    "predicted": {**_NUM_OR_NULL, "description": "mean w . V(s_0)"},
                    "achieved": {**_NUM_OR_NULL, "description": "mean discounted scalarized return"},
                    "gap": {**_NUM_OR_NULL, "description": "achieved - predicted"},
                    "relative_gap": {**_NUM_OR_NULL, "description": "gap / |predicted|"},
                    "survival": _FRACTION_OR_NULL,
                    "training_episodes": {"type": ["integer", "null"], "minimum": 0},
                    "training_share": _FRACTION_OR_NULL,
                },
            },
        },
        "training_logged": {"type": "boolean", "description": "metrics.csv has the wcount/ columns"},
        "overall": {
            "type": "object",
            "required": [
                "predicted_mean", "achieved_mean", "mean_gap", "mean_abs_gap", "correlation", "survival",
            ],
            "additionalProperties": _NUM_OR_NULL,
        },
        "per_sample": {
            "type": "object",
            "required": ["weights", "region", "predicted", "achieved", "achieved_undiscounted", "survived"],
            "properties": {
                "weights": _MATRIX,
                "region": {"type": "array", "items": {"type": "integer", "minimum": 0}},
                "predicted": _VECTOR,
                "achieved": _VECTOR,
                "achieved_undiscounted": _VECTOR,
                "survived": _BOOLS,
            },
        },
        "timing": {
            "type": "object",
            "required": ["env_steps", "seconds"],
            "properties": {
                "env_steps": {"type": "integer", "minimum": 0},
                "seconds": {"type": "number", "minimum": 0},
            },
        },
        "files": {"type": "object", "additionalProperties": {"type": "string"}},
    },
}  # fmt: skip
