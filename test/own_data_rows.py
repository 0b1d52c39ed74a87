"""Rows of the own-data study's tables, for the lab tests."""

from __future__ import annotations

from typing import Any

from lab import own_data


def _row(arm: str, **scores: float) -> dict[str, Any]:
    a = own_data.ARMS[arm]
    base = {
        "arm": arm,
        "study": a.study,
        "domain": a.domain,
        "observation": "partial" if a.partial else "full",
        "labels": a.labels,
        "length": a.length,
        "bags": a.bags,
        "seed": a.seed,
        "iterations": 400,
        "best_iteration": 200,
        "stopped_early": True,
        "train_seconds": 123.0,
        "train_episodes": 8,
        "val_episodes": 2,
        "test_episodes": 3,
        "offline_f1_1": 0.9,
        "offline_align": 0.8,
        "online_f1_1": 0.85,
        "online_align": 0.75,
        "label_free_online_f1_1": 0.82,
        "label_free_online_align": 0.77,
        **({"candidates_trained": a.candidates} if a.candidates > 1 else {}),
        "demonstrator": a.demonstrator,
        **({} if a.restart else {"restart": False}),
    }
    base.update(scores)
    return base
