"""What the whole suite shares: the add-on's folder importable as the package ``intrinsic_splats``.

The add-on's modules import each other relatively, so a test imports them as Blender does, inside a
package (``tests/support/addon_package.py``). Registering it here, before any test module is
imported, keeps that true whatever order the import lines of a test module are sorted in.
"""

from tests.support import addon_package  # noqa: F401
