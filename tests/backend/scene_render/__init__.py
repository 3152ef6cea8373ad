"""Tests of backend/scene_render/."""
