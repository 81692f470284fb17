"""Both brokers the stack may start (Mosquitto and the embedded one) against real paho clients."""

from __future__ import annotations

import pytest
from fleet_support import Inbox, wait_for

from guadal_cli.errors import GuadalError
from guadal_cli.fleet.broker import mosquitto_binary, port_accepts, start_broker

KINDS = ["embedded"] + (["mosquitto"] if mosquitto_binary() else [])


@pytest.fixture(scope="module", params=KINDS)
def broker(request):
    b = start_broker(request.param)
    yield b
    b.stop()


@pytest.fixture
def clients(broker):
    made = []

    def make(**kw):
        made.append(Inbox(broker.port, **kw))
        return made[-1]

    yield make
    for c in made:
        c.close()


def test_qos1_messages_all_arrive_in_order(broker, clients):
    sub, pub = clients(), clients()
    sub.subscribe("q/data", qos=1)
    infos = [pub.client.publish("q/data", str(i).encode(), qos=1) for i in range(200)]
    for info in infos:
        info.wait_for_publish(10)  # PUBACK from the broker
    sub.wait(lambda: len(sub.on("q/data")) == 200, 10, "200 QoS 1 messages were not delivered")
    assert [int(m.payload) for m in sub.on("q/data")] == list(range(200))
    assert {m.qos for m in sub.on("q/data")} == {1}


def test_retained_message_reaches_late_subscribers_and_can_be_cleared(broker, clients):
    pub = clients()
    pub.client.publish("r/status", b"online", qos=1, retain=True).wait_for_publish(10)
    late = clients()
    late.subscribe("r/status")
    late.wait(lambda: late.on("r/status"), 10, "the retained message was not delivered")
    assert late.on("r/status")[0].payload == b"online" and late.on("r/status")[0].retain
    pub.client.publish("r/status", b"", qos=1, retain=True).wait_for_publish(10)  # clear it
    pub.client.publish("r/marker", b"m", qos=1, retain=True).wait_for_publish(10)
    later = clients()
    later.subscribe("r/#")
    later.wait(lambda: later.on("r/marker"), 10, "the retained marker was not delivered")
    assert later.on("r/status") == []


def test_last_will_on_abrupt_disconnect_but_not_on_a_clean_one(broker, clients):
    watcher = clients()
    watcher.subscribe("w/+/status")
    clean = clients(will=("w/clean/status", b"offline", 1, True))
    clean.close()
    abrupt = clients(will=("w/abrupt/status", b"offline", 1, True))
    abrupt.client.loop_stop()
    abrupt.client.socket().close()  # the process died: no DISCONNECT packet
    watcher.wait(lambda: watcher.on("w/abrupt/status"), 10, "the last will was not published")
    assert watcher.on("w/abrupt/status")[0].payload == b"offline"
    assert watcher.on("w/clean/status") == []


def test_keepalive_expiry_publishes_the_will(broker, clients):
    watcher = clients()
    watcher.subscribe("k/status")
    silent = clients(keepalive=1, will=("k/status", b"offline", 1, False))
    silent.client.loop_stop()  # socket stays open, but no PINGREQ any more
    watcher.wait(lambda: watcher.on("k/status"), 10, "the broker did not expire the silent client")
    silent.client.socket().close()


def test_wildcards_match_exactly_the_topics_they_should(broker, clients):
    sub, pub = clients(), clients()
    sub.subscribe("g/vehicle/+/ack", "g/planner/#")
    for name in [
        "g/vehicle/1/ack",
        "g/vehicle/2/ack",
        "g/vehicle/1/telemetry",
        "g/vehicle/1/ack/x",
        "g/planner/status",
        "g/planner",
        "h/vehicle/1/ack",
        "g/marker",
    ]:
        pub.client.publish(name, b"x", qos=1).wait_for_publish(10)
    sub.subscribe("g/marker")
    pub.client.publish("g/marker", b"end", qos=1).wait_for_publish(10)
    sub.wait(lambda: sub.on("g/marker"), 10, "the marker was not delivered")
    assert sorted(m.topic for m in sub.messages if m.topic != "g/marker") == [
        "g/planner",
        "g/planner/status",
        "g/vehicle/1/ack",
        "g/vehicle/2/ack",
    ]


@pytest.mark.parametrize("kind", KINDS)
def test_broker_restarts_on_the_same_port_and_clients_reconnect(kind):
    first = start_broker(kind)
    try:
        client = Inbox(first.port)
        client.client.reconnect_delay_set(0.05, 0.5)
        client.subscribe("x/#")
        first.kill()
        wait_for(lambda: not client.client.is_connected(), 10, "the client did not notice the broker's death")
        second = start_broker(kind, port=first.port)
        try:
            client.wait(client.client.is_connected, 15, "the client did not reconnect")
            client.subscribe("x/#")
            client.client.publish("x/again", b"1", qos=1).wait_for_publish(10)
            client.wait(lambda: client.on("x/again"), 10, "no delivery after the restart")
        finally:
            client.close()
            second.stop()
        assert not port_accepts("127.0.0.1", first.port)
    finally:
        first.stop()


def test_unknown_broker_kind_is_one_sentence():
    with pytest.raises(GuadalError, match="broker kind 'rabbit' is unknown"):
        start_broker("rabbit")
