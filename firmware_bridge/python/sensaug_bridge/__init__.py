"""Placeholder: being written on the bridge-py branch."""
