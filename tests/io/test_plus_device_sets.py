"""The shipped PlusServer device sets (``thrsim trackers plus``): each streams, from its transform
repository, every TRANSFORM name thrsim reads, on thrsim's OpenIGTLink port; PLUS's message flow
(those names, one TRANSFORM each) is served by a real listener on 127.0.0.1 without a refusal."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ElementTree
from collections import defaultdict

import numpy as np
import pytest
from checkout_cli import run_main
from igtl_helpers import read_message, reamer_pose_mm, transform_message

from thrsim.config import KNOWN_TRACKER_DEVICES, OPENIGTLINK_PORT, IgtlConfig
from thrsim.io import igtl
from thrsim.io.plus import DEVICE_SETS
from thrsim.io.server import NAVIGATION_STATE

pytestmark = pytest.mark.timeout(60)


def _printed(monkeypatch, capsys, tracker: str) -> ElementTree.Element:
    code, out, err = run_main(monkeypatch, capsys, "trackers", "plus", "--tracker", tracker)
    assert code == 0 and err == ""
    return ElementTree.fromstring(out)


def _repository(root: ElementTree.Element) -> dict[str, set[str]]:
    """PLUS's transform repository as a graph: each tracked tool gives <Id>To<the device's
    ToolReferenceFrame>, each coordinate definition <From>To<To>; a transform is known both ways."""
    links: dict[str, set[str]] = defaultdict(set)
    for device in root.iterfind("DataCollection/Device"):
        for source in device.iterfind("DataSources/DataSource"):
            if source.get("Type") == "Tool":
                links[source.get("Id")].add(device.get("ToolReferenceFrame"))
                links[device.get("ToolReferenceFrame")].add(source.get("Id"))
    for transform in root.iterfind("CoordinateDefinitions/Transform"):
        matrix = np.array(transform.get("Matrix").split(), dtype=float).reshape(4, 4)
        assert np.allclose(matrix[3], [0, 0, 0, 1]) and np.allclose(matrix[:3, :3].T @ matrix[:3, :3], np.eye(3))
        links[transform.get("From")].add(transform.get("To"))
        links[transform.get("To")].add(transform.get("From"))
    return links


def _derivable(links: dict[str, set[str]], name: str) -> bool:
    """Whether the repository computes ``name`` (<From>To<To>): both frames known and connected."""
    for cut in range(1, len(name)):
        source, to, target = name[:cut], name[cut : cut + 2], name[cut + 2 :]
        if to != "To" or source not in links or target not in links:
            continue
        seen, frontier = {source}, [source]
        while frontier:
            frontier = [n for frame in frontier for n in links[frame] if n not in seen]
            seen.update(frontier)
        if target in seen:
            return True
    return False


@pytest.mark.parametrize("tracker", sorted(DEVICE_SETS))
def test_the_device_set_streams_every_name_thrsim_reads_on_its_port(monkeypatch, capsys, tracker):
    root = _printed(monkeypatch, capsys, tracker)
    server = root.find("PlusOpenIGTLinkServer")
    assert int(server.get("ListeningPort")) == OPENIGTLINK_PORT == IgtlConfig().port
    assert [m.get("Type") for m in server.iterfind("DefaultClientInfo/MessageTypes/Message")] == ["TRANSFORM"]
    streamed = [t.get("Name") for t in server.iterfind("DefaultClientInfo/TransformNames/Transform")]
    assert set(KNOWN_TRACKER_DEVICES) <= set(streamed) <= set(KNOWN_TRACKER_DEVICES)
    links = _repository(root)
    assert [name for name in streamed if not _derivable(links, name)] == []
    assert not _derivable(links, "ReamerToNowhere")  # the check can fail
    # the server's output channel exists and carries every tracked tool
    channels = {c.get("Id"): c for c in root.iterfind("DataCollection/Device/OutputChannels/OutputChannel")}
    carried = {s.get("Id") for s in channels[server.get("OutputChannelId")].iterfind("DataSource")}
    tools = {s.get("Id") for s in root.iterfind("DataCollection/Device/DataSources/DataSource")}
    assert carried == tools and len(tools) == 3


@pytest.mark.parametrize("tracker", sorted(DEVICE_SETS))
def test_json_lists_the_names_and_out_writes_the_same_file(monkeypatch, capsys, tmp_path, tracker):
    printed = ElementTree.tostring(_printed(monkeypatch, capsys, tracker))
    target = tmp_path / f"{tracker}.xml"
    code, out, err = run_main(monkeypatch, capsys, "trackers", "plus", "--tracker", tracker, "--out", str(target), "--json")
    assert code == 0, err
    listed = json.loads(out)
    assert listed["listening_port"] == OPENIGTLINK_PORT and set(listed["transforms"]) == set(KNOWN_TRACKER_DEVICES)
    assert listed["file"] == str(target) and ElementTree.tostring(ElementTree.parse(target).getroot()) == printed
    assert sorted(p.name for p in tmp_path.iterdir()) == [target.name]  # no temporary left


def test_an_unknown_tracker_is_one_line_and_writes_nothing(monkeypatch, capsys, tmp_path):
    code, out, err = run_main(monkeypatch, capsys, "trackers", "plus", "--tracker", "vicon", "--out", str(tmp_path / "x.xml"))
    assert (code, out) == (2, "") and err == "thrsim: error: --tracker: 'vicon' is not one of ndi, optitrack\n"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("tracker", sorted(DEVICE_SETS))
def test_plus_message_flow_is_served_by_the_listener(make_server, monkeypatch, capsys, tracker):
    """What PlusServer sends a client with this device set, one TRANSFORM per streamed name (mm on the
    wire), relayed to thrsim: every one is accepted and answered with the navigation state."""
    root = _printed(monkeypatch, capsys, tracker)
    streamed = [t.get("Name") for t in root.iterfind("PlusOpenIGTLinkServer/DefaultClientInfo/TransformNames/Transform")]
    server = make_server(IgtlConfig(port=0, max_other_devices=0))  # a name thrsim does not read would be refused
    with server.connect() as sock:
        for name in streamed:
            sock.sendall(transform_message(reamer_pose_mm(), device=name))
            reply = read_message(sock)
            assert (reply.type_name, reply.device_name) == ("STRING", NAVIGATION_STATE), igtl.unpack_status(reply.content)
    assert set(server.server.tracker.poses) == set(streamed)
    assert server.server.stats["unknown_devices"] == 0 and server.server.stats["transforms"] == len(streamed)
