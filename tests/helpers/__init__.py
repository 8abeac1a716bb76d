"""Test participants and helpers (processes the tests start beside the apps)."""
