"""What every command shares: one-line failures, output files and directories checked before any
work, option checks, task names and the default dataset directory."""
from __future__ import annotations

import json
import sys
from pathlib import Path

#: What ``bin/generate_data`` writes unless told: the default preset's (``cpu``) image size, so the
#: commands that train and evaluate it find the data where they look.
DEFAULT_IMAGE_SIZE = 96


def default_data_dir(image_size: int) -> str:
    """Datasets of different image sizes live side by side: ``data/<size>px``."""
    return f"data/{image_size}px"


def fail(message: str) -> None:
    """Print ``error: <message>`` as one line on stderr and exit with status 2."""
    text = " ".join(line.strip() for line in str(message).splitlines() if line.strip())
    print(f"error: {text}", file=sys.stderr)
    raise SystemExit(2)


def write_json(path: str | Path, payload) -> None:
    """Write ``payload`` as indented JSON to ``path`` atomically."""
    from envs.dataset import atomic_write_text

    atomic_write_text(Path(path), json.dumps(payload, indent=2))


def check_writable_dir(path: str | Path, label: str | None = None) -> Path:
    """Fail unless ``path`` is an existing directory this process can create files in (tried
    for real: permission bits say nothing for root or on read-only file systems). ``label``
    names the directory in the message (default ``output directory <path>``)."""
    import tempfile

    path = Path(path)
    label = label or f"output directory {path}"
    if not path.exists():
        fail(f"{label} does not exist")
    if not path.is_dir():
        fail(f"{label} is not a directory")
    try:
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-test-"):
            pass
    except OSError as err:
        fail(f"{label} is not writable ({err.strerror or err}); expected a directory you can write to")
    return path


def check_output_file(path: str | Path, option: str) -> Path:
    """Fail unless the file ``path`` (given with ``option``) can be written: not a directory,
    inside an existing writable directory."""
    path = Path(path)
    if path.is_dir():
        fail(f"{option} {path} is a directory; expected a file name")
    check_writable_dir(path.resolve().parent, f"directory {path.resolve().parent} (for {option} {path})")
    return path


def make_output_dir(path: str | Path, option: str) -> Path:
    """Create the directory ``path`` (given with ``option``) with its parents if needed; fail
    unless that works and the directory is writable."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        fail(f"cannot create {option} directory {path}: {err.strerror or err}")
    return check_writable_dir(path, f"{option} directory {path}")


def image_size(name: str, value: int) -> None:
    """Fail unless ``value`` is an image side the offscreen renderer supports."""
    from envs.panda import MAX_IMAGE_SIZE

    if not 1 <= value <= MAX_IMAGE_SIZE:
        fail(f"{name} must be between 1 and {MAX_IMAGE_SIZE} pixels, got {value}")


#: Seeds are 31-bit: JAX keys, NumPy generators and the episodes' seed layout all take them.
MAX_SEED = 2**31 - 1


def check_seed(name: str, value: int) -> None:
    if not 0 <= value <= MAX_SEED:
        fail(f"{name} must be an integer in [0, {MAX_SEED}], got {value}")


BACKEND_HELP = "physics back-end: native MuJoCo, MJX, or auto (MJX on an accelerator, else native; default)"


def task_help(many: bool = True) -> str:
    """``--task``'s help: the task names (and, with ``many``, lists and 'all')."""
    from envs.tasks import TASKS

    names = ", ".join(TASKS)
    return f"a task name ({names}), a comma-separated list, or 'all'" if many else f"one task name ({names})"


def task_names(arg: str) -> list[str]:
    from envs.evaluation import TASK_ORDER
    from envs.tasks import TASKS

    names = [t for t in TASK_ORDER if t in TASKS] if arg == "all" else arg.split(",")
    unknown = [n for n in names if n not in TASKS]
    if unknown:
        fail(f"unknown task {unknown[0]!r}; expected 'all' or a comma-separated list of: {', '.join(TASKS)}")
    return names


def positive(name: str, value: int) -> None:
    if value < 1:
        fail(f"{name} must be a positive integer, got {value}")
