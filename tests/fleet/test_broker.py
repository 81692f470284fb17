"""Both brokers the stack may start (Mosquitto and the embedded one) against real paho clients."""

from __future__ import annotations

import pytest
from support.fleet import Inbox, connect_refused, wait_for

from guadal_cli.channel.broker import mosquitto_binary, port_accepts, start_broker
from guadal_cli.errors import GuadalError

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


def test_a_connecting_client_gets_no_retained_message_it_did_not_subscribe_to(broker, clients):
    pub, subscriber = clients(), clients()
    subscriber.subscribe("n/#")  # someone else's subscription on the broker
    pub.client.publish("n/status", b"online", qos=1, retain=True).wait_for_publish(10)
    bystander = clients()
    bystander.subscribe("n-marker")
    pub.client.publish("n-marker", b"end", qos=1).wait_for_publish(10)
    bystander.wait(lambda: bystander.on("n-marker"), 10, "the marker was not delivered")
    assert [m.topic for m in bystander.messages] == ["n-marker"]


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


# --- authentication and ACL: the same rules in both brokers -----------------------------------------
@pytest.fixture(scope="module", params=KINDS)
def guarded(request, tmp_path_factory):
    """A broker with a two-boat fleet's generated users and ACL."""
    from guadal_cli.channel.credentials import FleetSecrets

    secrets = FleetSecrets.generate(tmp_path_factory.mktemp("secrets") / "s", "g", 2)
    b = start_broker(request.param, secrets=secrets)
    yield b, secrets
    b.stop()


def _login(secrets, user):
    return user, secrets.user_password_file(user).read_text().strip()


def test_anonymous_and_wrong_passwords_are_refused(guarded):
    broker, secrets = guarded
    assert connect_refused(broker.port) != ""
    assert connect_refused(broker.port, ("planner", "not-the-password")) != ""
    assert connect_refused(broker.port, ("intruder", "x")) != ""
    assert connect_refused(broker.port, _login(secrets, "planner")) == ""


def test_a_vehicle_user_publishes_only_on_its_own_topics(guarded):
    broker, secrets = guarded
    watcher = Inbox(broker.port, login=_login(secrets, "watcher"))
    boat1 = Inbox(broker.port, login=_login(secrets, "vehicle-1"))
    try:
        watcher.subscribe("g/#")
        forged = [
            "g/vehicle/0/command",
            "g/vehicle/0/ack",
            "g/vehicle/1/command",
            "g/planner/status",
            "g/planner/control",
        ]
        for name in forged:  # the broker acknowledges, and drops: a client learns nothing
            boat1.client.publish(name, b"forged", qos=1).wait_for_publish(10)
        boat1.client.publish("g/vehicle/1/ack", b"mine", qos=1).wait_for_publish(10)
        watcher.wait(lambda: watcher.on("g/vehicle/1/ack"), 10, "the boat's own ack was not delivered")
        # same client, in order: anything forged would have arrived before its own ack
        assert [m.topic for m in watcher.messages] == ["g/vehicle/1/ack"]
    finally:
        watcher.close()
        boat1.close()


def test_a_vehicle_user_cannot_read_another_vehicles_commands(guarded):
    broker, secrets = guarded
    boat1 = Inbox(broker.port, login=_login(secrets, "vehicle-1"))
    planner = Inbox(broker.port, login=_login(secrets, "planner"))
    try:
        # (Mosquitto grants the subscription and filters each delivery; amqtt refuses it: either
        # way nothing of vehicle 0 reaches vehicle 1)
        boat1.subscribe("g/vehicle/0/command", "g/vehicle/1/command")
        planner.client.publish("g/vehicle/0/command", b"for boat 0", qos=1).wait_for_publish(10)
        planner.client.publish("g/vehicle/1/command", b"for boat 1", qos=1).wait_for_publish(10)
        boat1.wait(lambda: boat1.on("g/vehicle/1/command"), 10, "boat 1 did not get its own command")
        assert boat1.on("g/vehicle/0/command") == []
    finally:
        boat1.close()
        planner.close()
