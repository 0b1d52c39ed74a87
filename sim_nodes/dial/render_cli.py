"""``python -m sim_nodes.dial.render_cli``: render the Dial scene or an expert episode offscreen.

See :mod:`sim_nodes.dial.render` for the output formats.
"""

from __future__ import annotations

import argparse

from sim_nodes.dial.expert import generate_episode
from sim_nodes.dial.render import save_episode, save_press_strip, save_scene_png


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Render the Dial scene or an expert episode offscreen.")
    parser.add_argument("--scene", help="write a still of the scene (home pose) to this PNG")
    parser.add_argument("--episode", type=int, help="seed of an expert episode to render")
    parser.add_argument("--out", default="dial_episode", help="output stem/directory for --episode")
    parser.add_argument("--every", type=int, default=2, help="render every n-th step")
    parser.add_argument("--strip", help="with --episode: also write a PNG with one frame per press")
    args = parser.parse_args(argv)
    if args.scene:
        print(save_scene_png(args.scene))
    if args.episode is not None:
        episode = generate_episode(args.episode)
        paths = save_episode(episode, args.out, every=args.every)
        print(f"wrote {len(paths)} file(s) under {paths[0].parent}")
        if args.strip:
            print(save_press_strip(episode, args.strip))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
