"""``antiscatter service install``: a systemd unit that runs ``antiscatter run --config FILE`` on boot.

The unit (the package's ``antiscatter.service.in``) runs this environment's own ``antiscatter`` as a
given user in the ``video`` and ``render`` groups, restarts it on failure and lets it take the
real-time priority and locked memory that ``[run] rt_priority`` / ``mlock`` ask for. Installing
writes the file only: the ``systemctl`` commands to run are printed, never run (docs/service.md).
"""

from __future__ import annotations

import argparse
import getpass
import grp
import logging
import os
import pwd
import sys
from importlib import resources
from pathlib import Path
from string import Template

from .errors import UsageError

__all__ = ["UNIT_DIR", "add_service_parser", "install_unit", "missing_groups", "render_unit", "service_main",
           "systemctl_steps"]

#: Where units a system administrator installs go (systemd.unit(5)); ``--unit-dir`` for elsewhere.
UNIT_DIR = Path("/etc/systemd/system")
#: LimitRTPRIO: the highest SCHED_FIFO priority the service may take, 0..99 (default 99: what
#: ``[run] rt_priority`` asks for is then always allowed; the config, not the unit, chooses it).
RTPRIO = 99
#: SupplementaryGroups of the unit: video (/dev/fb0, the camera), render (/dev/dri render nodes).
GROUPS = ("video", "render")


def add_service_parser(commands: argparse._SubParsersAction) -> None:
    """Register ``service`` and its ``install`` subcommand on the CLI's subparsers."""
    service = commands.add_parser(
        "service", help="run antiscatter on boot as a systemd service (install its unit)",
        description="Install a systemd unit that runs 'antiscatter run --config FILE' on boot "
                    "(docs/service.md: check it, see its log, stop it).")
    actions = service.add_subparsers(dest="service_command", metavar="ACTION")  # the CLI's one-line-error parser
    install = actions.add_parser(
        "install", help="write the unit file and print the systemctl commands that start it",
        description="Write a systemd unit running this environment's antiscatter with --config FILE as USER, "
                    "in the video and render groups, restarted on failure, with real-time and memlock "
                    "limits; print the systemctl commands to enable and start it (never run here).")
    install.add_argument("--config", required=True, metavar="FILE.toml",
                         help="the run config the service uses (checked to exist and parse)")
    install.add_argument("--user", help="the user the service runs as (default: the one who ran sudo, "
                                        "else the current user)")
    install.add_argument("--name", default="antiscatter", help="unit name, NAME.service (default antiscatter)")
    install.add_argument("--unit-dir", default=str(UNIT_DIR), metavar="DIR",
                         help=f"folder the unit is written to (default {UNIT_DIR})")
    install.add_argument("--rtprio", type=int, default=RTPRIO, metavar="N",
                         help=f"LimitRTPRIO: highest SCHED_FIFO priority allowed, 0..99 (default {RTPRIO})")
    install.add_argument("--overwrite", action="store_true", help="replace an existing unit of that name")
    install.add_argument("--dry-run", action="store_true", help="print the unit instead of writing it")


def _escape(text: str) -> str:
    """``text`` as one systemd ExecStart word: ``%`` and ``$`` doubled, quoted when it has blanks or quotes."""
    text = text.replace("%", "%%").replace("$", "$$")
    if any(c.isspace() or c in "\"'\\;" for c in text):
        text = '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return text


def _executable() -> list[str]:
    """This environment's antiscatter as absolute words: the script beside its python (a venv's bin/,
    not resolved, so the venv's packages are used), else ``python -m antiscatter``."""
    python = Path(sys.executable).absolute()
    script = python.parent / "antiscatter"
    if script.is_file() and os.access(script, os.X_OK):
        return [str(script)]
    return [str(python), "-m", "antiscatter"]


def _default_user() -> str:
    """The user who ran ``sudo`` (the unit is installed as root for them), else the current one."""
    return os.environ.get("SUDO_USER") or getpass.getuser()


def render_unit(config: str | Path, *, user: str, name: str = "antiscatter",
                executable: list[str] | None = None, rtprio: int = RTPRIO) -> str:
    """The unit file's text for ``antiscatter run --config CONFIG``.

    Parameters
    ----------
    config : the run config (TOML); must exist and parse (bad ones raise UsageError, one line).
    user : the account the service runs as; must exist.
    name : the unit's name without ``.service``: letters, digits, ``-``, ``_``, ``.``, ``@``.
    executable : ExecStart's command words (default: this environment's antiscatter).
    rtprio : LimitRTPRIO, 0..99.
    """
    from .config import load_config

    config = Path(config).absolute()
    if not config.is_file():
        raise UsageError(f"--config {config}: no such config file")
    load_config(config)  # a bad key or value fails now, not at every restart
    try:
        pwd.getpwnam(user)
    except KeyError:
        raise UsageError(f"--user {user}: no such user on this machine") from None
    if not name or not all(c.isalnum() or c in "-_.@" for c in name) or name.endswith(".service"):
        raise UsageError(f"--name {name!r}: allowed letters, digits, '-', '_', '.', '@' (no .service)")
    if not 0 <= rtprio <= 99:
        raise UsageError(f"--rtprio {rtprio}: allowed 0..99")
    words = (executable or _executable()) + ["run", "--config", str(config)]
    template = Template(resources.files("antiscatter").joinpath("antiscatter.service.in").read_text("utf-8"))
    return template.substitute(
        name=f"{name}.service", config_text=_escape(str(config)), user=_escape(user),
        working_directory=_escape(str(config.parent)), exec_start=" ".join(_escape(w) for w in words),
        groups=" ".join(GROUPS), rtprio=rtprio, memlock="infinity")


def install_unit(text: str, unit_dir: str | Path = UNIT_DIR, name: str = "antiscatter", *,
                 overwrite: bool = False) -> Path:
    """Write ``text`` as ``UNIT_DIR/NAME.service`` (mode 644); an existing unit is kept unless ``overwrite``."""
    unit_dir = Path(unit_dir)
    path = unit_dir / f"{name}.service"
    if not unit_dir.is_dir():
        raise UsageError(f"--unit-dir {unit_dir}: no such folder")
    if path.exists() and not overwrite:
        raise UsageError(f"{path}: exists; --overwrite replaces it")
    try:
        path.write_text(text, encoding="utf-8")
        path.chmod(0o644)
    except PermissionError:
        raise UsageError(f"{path}: permission denied; run with sudo (or --unit-dir DIR)") from None
    return path


def missing_groups(groups: tuple[str, ...] = GROUPS) -> list[str]:
    """The unit's SupplementaryGroups that this machine lacks (systemd fails the start on one)."""
    missing = []
    for group in groups:
        try:
            grp.getgrnam(group)
        except KeyError:
            missing.append(group)
    return missing


def systemctl_steps(name: str = "antiscatter") -> str:
    """The commands that load, start, check, follow and stop the unit, as lines to print."""
    unit = f"{name}.service"
    return "\n".join([
        "now run:",
        "  sudo systemctl daemon-reload",
        f"  sudo systemctl enable --now {unit}    # start it, and on every boot",
        f"check it:  systemctl status {unit}",
        f"its log:   journalctl -u {unit} -f",
        f"stop it:   sudo systemctl stop {unit}    (not on boot either: sudo systemctl disable {unit})"])


def service_main(args: argparse.Namespace) -> int:
    """``antiscatter service ACTION``: exit code 0; 2 (UsageError, raised) for bad input."""
    if args.service_command != "install":
        raise UsageError("an action is needed: install (see antiscatter service --help)")
    user = args.user or _default_user()
    text = render_unit(args.config, user=user, name=args.name, rtprio=args.rtprio)
    if args.dry_run:
        sys.stdout.write(text)
        return 0
    path = install_unit(text, args.unit_dir, args.name, overwrite=args.overwrite)
    for group in missing_groups():
        logging.getLogger("antiscatter.service").warning(
            f"no group {group} here: systemd will refuse to start the unit until it exists "
            f"(sudo groupadd --system {group})")
    print(f"wrote {path} (runs as {user}: antiscatter run --config {Path(args.config).absolute()})")
    print(systemctl_steps(args.name))
    return 0
