"""``antiscatter service install``: the systemd unit written to a temp folder, never to /etc, and
no systemctl run."""

from __future__ import annotations

import configparser
import getpass
import os
import shlex
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

from antiscatter.service import GROUPS, RTPRIO, render_unit

USER = getpass.getuser()


def _config(folder: Path, text: str = "[run]\nframes = 30\n\n[output]\noutputs = [\"none\"]\n") -> Path:
    path = folder / "run.toml"
    path.write_text(text)
    return path


def _parse(path: Path) -> configparser.ConfigParser:
    parser = configparser.ConfigParser(strict=False, interpolation=None, delimiters=("=",))
    parser.optionxform = str  # systemd keys are case-sensitive
    parser.read(path)
    return parser


def test_install_writes_a_unit_that_runs_this_antiscatter_with_the_config(tmp_path, cli):
    config = _config(tmp_path)
    units = tmp_path / "units"
    units.mkdir()
    result = cli("service", "install", "--config", str(config), "--unit-dir", str(units), "--user", USER)
    assert result.code == 0, result.err
    unit = units / "antiscatter.service"
    assert stat.S_IMODE(unit.stat().st_mode) == 0o644
    parsed = _parse(unit)
    assert parsed.sections() == ["Unit", "Service", "Install"]
    service = parsed["Service"]
    assert service["User"] == USER
    assert service["Restart"] == "on-failure"
    assert service["LimitRTPRIO"] == str(RTPRIO) == "99"
    assert service["LimitMEMLOCK"] == "infinity"
    assert service["SupplementaryGroups"].split() == list(GROUPS) == ["video", "render"]
    assert service["WorkingDirectory"] == str(config.parent)
    assert parsed["Install"]["WantedBy"] == "multi-user.target"
    executable, *words = shlex.split(service["ExecStart"])
    assert words == ["run", "--config", str(config)]
    assert os.path.isabs(executable) and os.access(executable, os.X_OK)
    assert Path(executable).name == "antiscatter"
    # the commands to run are printed, none is run
    for line in ("sudo systemctl daemon-reload", "sudo systemctl enable --now antiscatter.service",
                 "systemctl status antiscatter.service", "journalctl -u antiscatter.service",
                 "sudo systemctl stop antiscatter.service"):
        assert line in result.out


def test_dry_run_prints_the_unit_and_writes_nothing(tmp_path, cli):
    config = _config(tmp_path)
    result = cli("service", "install", "--config", str(config), "--unit-dir", str(tmp_path), "--user", USER,
                 "--dry-run")
    assert result.code == 0, result.err
    assert result.out == render_unit(config, user=USER)
    assert "ExecStart=" in result.out and not (tmp_path / "antiscatter.service").exists()


def test_a_config_path_with_blanks_and_percent_is_quoted_for_systemd(tmp_path):
    folder = tmp_path / "my configs 100%"
    folder.mkdir()
    config = _config(folder)
    text = render_unit(config, user=USER, executable=["/opt/venv/bin/antiscatter"])
    exec_start = next(line for line in text.splitlines() if line.startswith("ExecStart="))
    assert exec_start == f'ExecStart=/opt/venv/bin/antiscatter run --config "{str(config).replace("%", "%%")}"'


@pytest.mark.parametrize("args, message", [
    (["--config", "{tmp}/missing.toml"], "--config {tmp}/missing.toml: no such config file"),
    (["--config", "{tmp}/bad.toml"], "{tmp}/bad.toml: unknown section [lamp]; allowed: "),
    (["--config", "{tmp}/run.toml", "--user", "no-such-user-here"], "--user no-such-user-here: no such user"),
    (["--config", "{tmp}/run.toml", "--rtprio", "100"], "--rtprio 100: allowed 0..99"),
    (["--config", "{tmp}/run.toml", "--name", "a b"], "--name 'a b': allowed letters, digits"),
    (["--config", "{tmp}/run.toml", "--unit-dir", "{tmp}/nowhere"], "--unit-dir {tmp}/nowhere: no such folder"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, cli, args, message):
    _config(tmp_path)
    (tmp_path / "bad.toml").write_text("[lamp]\nlevel = 1\n")
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    result = cli("service", "install", "--unit-dir", str(tmp_path), *args)
    assert result.code == 2
    assert result.err.count("\n") == 1
    assert result.err.startswith("antiscatter service: error: " + message.replace("{tmp}", str(tmp_path)))
    assert not (tmp_path / "antiscatter.service").exists()


def test_an_existing_unit_is_kept_unless_overwrite(tmp_path, cli):
    config = _config(tmp_path)
    unit = tmp_path / "antiscatter.service"
    unit.write_text("mine\n")
    result = cli("service", "install", "--config", str(config), "--unit-dir", str(tmp_path), "--user", USER)
    assert result.code == 2 and result.err == f"antiscatter service: error: {unit}: exists; --overwrite replaces it\n"
    assert unit.read_text() == "mine\n"
    result = cli("service", "install", "--config", str(config), "--unit-dir", str(tmp_path), "--user", USER,
                 "--overwrite")
    assert result.code == 0 and "ExecStart=" in unit.read_text()


def test_service_without_an_action_is_one_line_exit_2(cli):
    result = cli("service")
    assert result.code == 2
    assert result.err == "antiscatter service: error: an action is needed: install (see antiscatter service --help)\n"


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed here")
def test_systemd_analyze_verify_accepts_the_unit_and_rejects_a_broken_one(tmp_path, cli):
    config = _config(tmp_path)
    assert cli("service", "install", "--config", str(config), "--unit-dir", str(tmp_path), "--user", USER).code == 0
    unit = tmp_path / "antiscatter.service"
    verify = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, timeout=60)
    assert verify.returncode == 0, verify.stderr
    broken = tmp_path / "broken.service"  # negative control: verify does check ExecStart
    broken.write_text("\n".join("ExecStart=/nonexistent/antiscatter run" if line.startswith("ExecStart=") else line
                                for line in unit.read_text().splitlines()) + "\n")
    verify = subprocess.run(["systemd-analyze", "verify", str(broken)], capture_output=True, text=True, timeout=60)
    assert verify.returncode != 0 and "/nonexistent/antiscatter" in verify.stderr
