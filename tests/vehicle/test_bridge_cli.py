"""``guadal bridge`` on bad input: one sentence, exit code 2, no traceback, nothing left running."""

from __future__ import annotations

import socket

import pytest
from typer.testing import CliRunner

from guadal_cli.app import app


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture
def run(lake):
    _, _, map_path = lake

    def invoke(*args, config: str | None = None, tmp=None):
        argv = ["bridge", *args]
        if config is not None:
            path = tmp / "bridge.yaml"
            path.write_text(config.replace("MAP", str(map_path)))
            argv += ["--config", str(path)]
        result = CliRunner().invoke(app, argv)
        return result.exit_code, result.output

    return invoke


def test_bad_settings_get_one_sentence(run, tmp_path, lake):
    map_path = str(lake[2])
    base = ["--vehicle-id", "0", "--mavlink", "udpin:127.0.0.1:0"]
    cases = [
        (
            base + ["--map", map_path, "--broker", "http://host:1883"],
            "must look like mqtt://host:port or mqtt://user@host:port",
        ),
        (base + ["--map", str(tmp_path / "nope.json")], "nope.json' does not exist"),
        (base + ["--map", map_path, "--sensor", "synthetik:x.csv"], "Did you mean 'synthetic'?"),
        (
            base + ["--map", map_path, "--sensor", "synthetic:" + str(tmp_path / "t.csv")],
            "sensor.path: file",
        ),
        (["--mavlink", "udpin:127.0.0.1:0", "--map", map_path], "vehicle_id: required, but missing."),
        (base + ["--map", map_path, "--failsafe-timeout", "-1"], "failsafe_timeout: must be greater than 0"),
    ]
    for argv, sentence in cases:
        code, output = run(*argv)
        assert code == 2, output
        assert sentence in output and "Traceback" not in output
        assert output.count("error:") == 1


def test_config_file_keys_are_checked(run, tmp_path):
    code, output = run(
        config="vehicle_id: 0\nmavlink: udpin:127.0.0.1:0\nmap: MAP\nfailsafe_timout: 3\n", tmp=tmp_path
    )
    assert code == 2 and "failsafe_timout: unknown key (allowed:" in output and "failsafe_timeout" in output
    code, output = run(config="- just\n- a list\n", tmp=tmp_path)
    assert code == 2 and "must be a mapping of settings" in output


def test_no_autopilot_is_a_clear_error(run, tmp_path, lake):
    code, output = run(
        "--vehicle-id",
        "0",
        "--mavlink",
        f"udpin:127.0.0.1:{free_udp_port()}",
        "--map",
        str(lake[2]),
        "--connect-timeout",
        "0.5",
    )
    assert code == 2
    assert "no autopilot heartbeat on 'udpin:127.0.0.1:" in output and "within 0.5 s" in output


def test_sigterm_while_waiting_for_the_autopilot_exits_quietly(lake, tmp_path):
    import signal
    import subprocess

    from support.fleet import wait_for
    from support.vehicle import GUADAL

    log = tmp_path / "bridge.log"
    with open(log, "w") as out:
        proc = subprocess.Popen(
            GUADAL
            + [
                "bridge",
                "--vehicle-id",
                "0",
                "--mavlink",
                f"udpin:127.0.0.1:{free_udp_port()}",
                "--map",
                str(lake[2]),
            ],
            stdout=out,
            stderr=subprocess.STDOUT,
        )
        try:
            wait_for(
                lambda: "waiting for the autopilot" in log.read_text(), 20, "the bridge did not start waiting"
            )
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(10) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert "Traceback" not in log.read_text() and "error" not in log.read_text().lower()


def test_config_file_paths_are_relative_to_the_file_and_options_win(tmp_path):
    from pathlib import Path

    from guadal_cli.vehicle.config import load_config

    deploy = tmp_path / "deploy"
    deploy.mkdir()
    (deploy / "boat2.password").write_text("s@cret\n")
    (deploy / "fleet.key").write_text("0123456789abcdef0123456789abcdef\n")
    (deploy / "bridge.yaml").write_text(
        "vehicle_id: 2\nmavlink: /dev/serial0\nmap: lake.json\nsensor: {type: synthetic, path: truth.csv}\n"
        "broker: mqtts://boat2@broker.example.org\npassword_file: boat2.password\nkey_file: fleet.key\n"
        "failsafe_timeout: 20\n"
    )
    config = load_config(deploy / "bridge.yaml", {"failsafe_timeout": 5.0, "vehicle_id": None})
    assert config.map_path() == deploy / "lake.json"
    assert config.sensor_base_dir == deploy
    assert (config.vehicle_id, config.failsafe_timeout) == (2, 5.0)
    endpoint = config.endpoint()
    assert (endpoint.host, endpoint.port, endpoint.tls, endpoint.username) == (
        "broker.example.org",
        8883,
        True,
        "boat2",
    )
    assert endpoint.password.get_secret_value() == "s@cret"
    assert "s@cret" not in endpoint.url and "s@cret" not in repr(endpoint)  # safe to log
    assert config.fleet_key() == b"0123456789abcdef0123456789abcdef"
    # a sensor given on the command line is relative to where it was typed, not to the file
    config = load_config(deploy / "bridge.yaml", {"sensor": "synthetic:here.csv"})
    assert config.sensor_base_dir is None and config.map_path() == deploy / "lake.json"
    assert load_config(None, {"vehicle_id": 0, "mavlink": "tcp:h:1", "map": "m.json"}).map_path() == Path(
        "m.json"
    )


def test_a_missing_key_file_or_short_key_is_one_sentence(tmp_path):
    import pytest

    from guadal_cli.errors import GuadalError
    from guadal_cli.vehicle.config import load_config

    base = {"vehicle_id": 0, "mavlink": "tcp:h:1", "map": "m.json"}
    with pytest.raises(GuadalError, match=r"key_file: cannot read '.*nope.key'"):
        load_config(None, {**base, "key_file": str(tmp_path / "nope.key")})
    (tmp_path / "short.key").write_text("abc\n")
    with pytest.raises(GuadalError, match="key_file: the fleet key has 3 bytes; use at least 16"):
        load_config(None, {**base, "key_file": str(tmp_path / "short.key")})
