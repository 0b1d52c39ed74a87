"""Where shipped files live, in a source checkout and in an installed (colcon/pip) tree."""

from __future__ import annotations

from pathlib import Path

SOURCE_ROOT = Path(__file__).resolve().parents[1]


def config_file(name: str) -> Path:
    """Path of a shipped ``config/<name>``: the checkout's copy, else the package share directory."""
    local = SOURCE_ROOT / "config" / name
    if local.is_file():
        return local
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError as exc:  # pragma: no cover - ament_index comes with the ROS wheels
        raise FileNotFoundError(f"config/{name} is not next to the sources; ament_index is missing") from exc
    try:
        shared = Path(get_package_share_directory("ompn_ros")) / "config" / name
    except (PackageNotFoundError, ValueError, OSError) as exc:
        raise FileNotFoundError(f"config/{name}: not in {SOURCE_ROOT / 'config'} and ompn_ros is not in "
                                "the ament index (source install/setup.bash)") from exc
    if not shared.is_file():
        raise FileNotFoundError(f"config/{name} is missing from {shared.parent}")
    return shared
