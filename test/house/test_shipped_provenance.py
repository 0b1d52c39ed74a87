"""What ships is what the product's pipeline makes: every shipped checkpoint was trained by
``ompn_train`` with the current config and defaults (``python -m lab.ship_product``), carries the
detector ``ompn_train`` chose, and reports held-out metrics of the node's replay with that detector.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml

import ompn_ros
from lab.ship_product import PIPELINE, commands
from ompn_ros.checkpoints import SHIPPED, shipped_checkpoint
from ompn_ros.detect.settings import load_detector_settings
from ompn_ros.model.config import OMPNConfig

ROOT = Path(__file__).resolve().parents[2]
DATA_FIELDS = ("obs_dim", "action_type", "action_dim")


def _provenance(domain: str) -> dict[str, Any]:
    found: dict[str, Any] = json.loads((shipped_checkpoint(domain) / "provenance.json").read_text())
    return found


@pytest.mark.parametrize("domain", sorted(SHIPPED))
def test_shipped_checkpoint_comes_from_the_product_pipeline(domain: str) -> None:
    record = _provenance(domain)
    assert record.get("pipeline") == PIPELINE, f"{domain}: not shipped by python -m {PIPELINE}"
    assert record["version"] == ompn_ros.__version__, (
        f"{domain}: shipped by version {record['version']}, the package is {ompn_ros.__version__}: "
        f"run python -m {PIPELINE} {domain}")
    expected = {name: " ".join(argv) for name, argv in commands(domain, Path("runs/ship")).items()}
    assert record["commands"] == expected, f"{domain}: the pipeline's commands changed since it shipped"
    assert record["commands"]["train"].startswith("ompn_train ")


@pytest.mark.parametrize("domain", sorted(SHIPPED))
def test_shipped_detector_is_the_one_ompn_train_chose(domain: str) -> None:
    record = _provenance(domain)
    detector = load_detector_settings(shipped_checkpoint(domain))
    assert detector.source == "shipped"
    assert f"ompn_train {record['version']} ({record['commands']['train']})" in detector.provenance


@pytest.mark.parametrize("domain", sorted(SHIPPED))
def test_shipped_model_has_the_current_config(domain: str) -> None:
    """The shipped model's config is what ``config/train_<domain>.yaml`` builds today."""
    shipped = json.loads((shipped_checkpoint(domain) / "config.json").read_text())
    model = yaml.safe_load((ROOT / f"config/train_{domain}.yaml").read_text())["model"]
    data = DATA_FIELDS
    if model.get("still_tolerance", "auto") == "auto":  # chosen from the training bags (0 on expert data)
        model.pop("still_tolerance", None)
        data = (*DATA_FIELDS, "still_tolerance")
    today = OMPNConfig.from_dict({**model, **{k: shipped[k] for k in data}})
    assert OMPNConfig.from_dict(shipped) == today, (
        f"{domain}: config/train_{domain}.yaml changed since the checkpoint shipped; "
        f"run python -m {PIPELINE} {domain}")


@pytest.mark.parametrize("domain", sorted(SHIPPED))
def test_shipped_metrics_are_held_out_replays(domain: str) -> None:
    """The reported figures are ``ompn_segment``'s on demonstrations the pipeline never trained on."""
    record = _provenance(domain)
    metrics = record["held_out_metrics"]
    assert "--seed 0 " in record["commands"]["collect_train"]
    assert "--seed 0 " not in record["commands"]["collect_test"]
    assert record["commands"]["segment"].split()[2] in record["commands"]["collect_test"]
    for key in ("align", "f1_tol1"):
        assert 0.0 <= metrics["online"][key] <= 1.0, f"{domain}: online {key} missing or out of range"
