"""``--ros2-dds [DOMAIN]`` on the command line: which graph it names, and its errors in one line."""

from __future__ import annotations

import pytest

from uavmpc.apps.cli import main
from uavmpc.drivers.ros2 import dds_where, open_graph


def test_the_domain_is_given_or_ros_domain_id_or_0(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    assert dds_where(None) == "dds/0"
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    assert dds_where(None) == "dds/42"
    assert dds_where(7) == "dds/7"
    with pytest.raises(ValueError, match=r"0\.\.232"):
        dds_where(233)
    with pytest.raises(ValueError, match="dds/<domain id>"):
        open_graph("dds/", "uavmpc_x")


@pytest.mark.parametrize("command", [["run", "swap_through_static"],
                                     ["swarm", "swap_through_static"],
                                     ["node", "--id", "uav1", "--priority", "1"]])
def test_bad_ros2_dds_arguments_are_one_line_and_exit_code_2(
        command: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main([*command, "--ros2", "tcp/localhost:7447", "--ros2-dds"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--ros2 and --ros2-dds are exclusive" in err
    assert main([*command, "--ros2-dds", "300"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "0..232" in err
