"""Message types and their binary encoding."""
