"""The command channel between the planner, the vehicle bridges and operators, in one place.

protocol.py     topics, message types and their checks, HMAC-SHA256 signing (both sides import it)
session.py      which command a bridge obeys: sessions and sequence numbers
client.py       Channel: the one MQTT client (login, TLS, will, signing) feeding a queue
credentials.py  generated broker users, their ACL, the fleet key, private files
broker.py       a private Mosquitto or embedded broker enforcing those users and ACL
"""
