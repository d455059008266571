"""The shipped systemd unit (deploy/mavservo.service) can start the shipped signed configs.

The new-user trial installed the key as README said (root, mode 640) and the unit runs as a
``DynamicUser``, which cannot read it: the signed configs failed at start-up in a restart
loop. The unit now hands the config and the key over as systemd credentials. These tests do
what systemd does at start (copy each ``LoadCredential=ID:PATH`` to ``$CREDENTIALS_DIRECTORY/ID``,
expand ``${CREDENTIALS_DIRECTORY}`` in ``ExecStart=``), with ``/etc/mavservo`` moved to a
temporary directory, and load the config the command line names with the project's loader:
everything the service reads must come from the credentials directory, never from
``/etc/mavservo``, where the key is root's alone. ``systemd-analyze verify`` checks the unit's
syntax where it is installed.
"""

from __future__ import annotations

import secrets
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from mavservo.config.loader import load_config
from tests.support.paths import REPO

ROOT = REPO
UNIT = ROOT / "deploy" / "mavservo.service"
ETC = "/etc/mavservo/"


def unit_settings(text: str) -> list[tuple[str, str, str]]:
    """``(section, key, value)`` in file order; systemd allows a key more than once."""
    settings: list[tuple[str, str, str]] = []
    section = ""
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1]
            continue
        key, _, value = line.partition("=")
        settings.append((section, key.strip(), value.strip()))
    return settings


def service(key: str) -> list[str]:
    return [v for s, k, v in unit_settings(UNIT.read_text()) if s == "Service" and k == key]


def start_like_systemd(etc: Path, credentials: Path) -> list[str]:
    """Set up the credentials and return ExecStart's argv as the service would get it."""
    for entry in service("LoadCredential"):
        name, _, source = entry.partition(":")
        assert source.startswith(ETC), f"LoadCredential={entry}: expected a file in {ETC}"
        shutil.copyfile(etc / source.removeprefix(ETC), credentials / name)
    (command,) = service("ExecStart")
    argv = shlex.split(command.replace("${CREDENTIALS_DIRECTORY}", str(credentials)))
    return [str(etc / a.removeprefix(ETC)) if a.startswith(ETC) else a for a in argv]


@pytest.mark.parametrize("example", ["plane-surfaces.yaml", "gimbal.yaml"])
def test_the_service_reads_its_config_and_signing_key_only_from_its_credentials(
    tmp_path: Path, example: str
) -> None:
    etc = tmp_path / "etc-mavservo"  # installed as README says
    etc.mkdir()
    shutil.copyfile(ROOT / "config" / example, etc / "mavservo.yaml")
    key = secrets.token_hex(32)
    (etc / "signing.key").write_text(key + "\n")
    (etc / "signing.key").chmod(0o600)
    credentials = tmp_path / "credentials"
    credentials.mkdir()

    argv = start_like_systemd(etc, credentials)
    config_path = Path(argv[argv.index("--config") + 1])
    assert config_path.parent == credentials, argv
    config = load_config(config_path)
    signing = config.mavlink.signing
    assert signing is not None and signing.key_file is not None
    assert signing.key_file.parent == credentials  # not /etc/mavservo: root's alone
    assert signing.secret_key() == bytes.fromhex(key)


def test_the_key_credential_is_on_because_every_hardware_example_signs_with_it() -> None:
    # The unit ships with LoadCredential=signing.key enabled (an unsigned config has to comment
    # it out): that default is right only while the hardware examples sign with that key name.
    credentials = {entry.partition(":")[0] for entry in service("LoadCredential")}
    hardware = []
    for path in sorted((ROOT / "config").glob("*.yaml")):
        document = yaml.safe_load(path.read_text())
        channels = [str(bus.get("channel", "")) for bus in document["can"]["buses"]]
        if any(channel.startswith("/dev/") for channel in channels):
            hardware.append(path.name)
            signing = document["mavlink"].get("signing") or {}
            assert signing.get("key_file") in credentials, (path.name, signing, credentials)
    assert hardware == ["gimbal.yaml", "plane-surfaces.yaml"]


def test_the_unit_runs_as_a_dynamic_user_in_dialout() -> None:
    # the reason the key must come as a credential; if this changes, revisit the credentials
    assert service("DynamicUser") == ["yes"]
    assert service("SupplementaryGroups") == ["dialout"]


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze missing")
def test_systemd_analyze_verify_accepts_the_unit(tmp_path: Path) -> None:
    # verify insists that the ExecStart binary exists: point it at this environment's mavservo
    mavservo = Path(sys.executable).with_name("mavservo")
    if not mavservo.exists():
        pytest.skip("the mavservo console script is not installed next to this Python")
    unit = tmp_path / "mavservo.service"
    unit.write_text(UNIT.read_text().replace("/opt/mavservo/bin/mavservo", str(mavservo)))
    result = subprocess.run(
        ["systemd-analyze", "verify", str(unit)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    assert "mavservo.service" not in result.stderr, result.stderr  # no warning about it
