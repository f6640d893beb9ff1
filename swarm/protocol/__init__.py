"""The wire protocol and its clients: schema, Zenoh sessions, the server's and coordinator's clients.

Everything a process needs to speak ``docs/protocol.md``; no role lives here.
"""
