"""The fleet on a network: one per-segment engine, an in-memory and an MQTT transport, the roadside service."""
