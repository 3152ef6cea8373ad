"""The test suite: tests/backend/<room>/ mirrors the backend, tests/blender/ the add-on, tests/contract/ what both share."""
