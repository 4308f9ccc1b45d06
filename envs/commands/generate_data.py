"""``bin/generate_data``: expert demonstrations (train and test splits) for tasks."""
from __future__ import annotations

import argparse

from envs.commands.common import (DEFAULT_IMAGE_SIZE, check_seed, default_data_dir, fail, image_size,
                                  make_output_dir, positive, task_help, task_names)
from envs.platform import setup


def main(argv: list[str] | None = None) -> None:
    setup()  # the headless GL and XLA back-ends, before mujoco or jax are imported

    parser = argparse.ArgumentParser(description="Generate expert demonstrations (train and test splits) for tasks.")
    parser.add_argument("--task", required=True, help=task_help())
    parser.add_argument("--train", type=int, default=1000, help="training episodes (default 1000)")
    parser.add_argument("--test", type=int, default=100, help="test episodes (default 100)")
    parser.add_argument("--out", help="dataset root directory (default ./data/<image-size>px)")
    parser.add_argument("--seed", type=int, default=0, help="base seed; train and test seeds never overlap")
    parser.add_argument("--image-size", type=int, default=DEFAULT_IMAGE_SIZE,
                        help=f"image width = height (default {DEFAULT_IMAGE_SIZE}, the default preset's; the paper's is 256)")
    parser.add_argument("--workers", type=int, default=None, help="physics threads (default: one per core)")
    args = parser.parse_args(argv)
    for name in ("train", "test"):
        positive(f"--{name}", getattr(args, name))
    image_size("--image-size", args.image_size)
    check_seed("--seed", args.seed)
    if args.workers is not None:
        positive("--workers", args.workers)
    names = task_names(args.task)
    import time

    from envs.dataset import DatasetError, generate_split, load_split, size_in_name
    from envs.tasks import get_task

    named = size_in_name(args.out) if args.out else None
    if named is not None and named != args.image_size:
        fail(f"--out {args.out} is named for {named}px images but --image-size is {args.image_size}; "
             f"pass --image-size {named} or another --out")
    out = make_output_dir(args.out or default_data_dir(args.image_size), "--out")

    for name in names:
        task = get_task(name, args.image_size)
        start = time.perf_counter()
        try:
            for split, n in (("train", args.train), ("test", args.test)):
                generate_split(task, split, n, out, base_seed=args.seed, workers=args.workers)
            meta = load_split(out, name, "train").meta
        except (DatasetError, ValueError, RuntimeError, OSError) as err:
            fail(f"{name}: {err}")
        print(f"{name}: {args.train} train + {args.test} test episodes at {args.image_size}px in "
              f"{time.perf_counter() - start:.1f} s (expert success {meta['expert_success_rate']:.1%}) -> {out / name}")
