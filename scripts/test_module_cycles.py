"""Unit tests of scripts/module-cycles.py on tiny crates written into a scratch directory.

    python3 -m unittest scripts/test_module_cycles.py
"""

from __future__ import annotations

import importlib.util
import sys
import tempfile
import unittest
from pathlib import Path

_SPEC = importlib.util.spec_from_file_location(
    "module_cycles", Path(__file__).resolve().parent / "module-cycles.py"
)
assert _SPEC is not None and _SPEC.loader is not None
cycles = importlib.util.module_from_spec(_SPEC)
# Registered before it runs: its dataclass looks itself up in sys.modules.
sys.modules["module_cycles"] = cycles
_SPEC.loader.exec_module(cycles)


def write_crate(root: Path, files: dict[str, str]) -> None:
    """A crate `demo` under `root` with `files` (paths under src/) as its sources."""
    (root / "demo").mkdir()
    (root / "demo" / "Cargo.toml").write_text('[package]\nname = "demo"\n')
    for name, text in files.items():
        path = root / "demo" / "src" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


class ModuleCycles(unittest.TestCase):
    def rings_of(self, files: dict[str, str]) -> list[str]:
        with tempfile.TemporaryDirectory() as scratch:
            write_crate(Path(scratch), files)
            return cycles.rings(Path(scratch))

    def test_two_files_naming_each_other_are_a_ring(self) -> None:
        found = self.rings_of(
            {
                "lib.rs": "mod a;\nmod b;\n",
                "a.rs": "use crate::b::B;\npub struct A;\n",
                "b.rs": "use crate::{a::A, c};\npub struct B;\n",
            }
        )
        self.assertEqual(len(found), 1, found)
        self.assertIn("a -> b  (demo/src/a.rs:1)", found[0])
        self.assertIn("b -> a  (demo/src/b.rs:1)", found[0])

    def test_a_chain_and_the_crate_root_are_no_ring(self) -> None:
        found = self.rings_of(
            {
                # The root names both, and both name the root: no ring counts through it.
                "lib.rs": "mod a;\nmod b;\npub use a::A;\npub struct Error;\n",
                "a.rs": "use crate::b::B;\nuse crate::Error;\npub struct A;\n",
                "b.rs": "use crate::Error;\n// use crate::a::A; (a comment)\n"
                'const S: &str = "crate::a::A";\npub struct B;\n',
            }
        )
        self.assertEqual(found, [])

    def test_a_test_module_super_is_its_own_file(self) -> None:
        found = self.rings_of(
            {
                "lib.rs": "mod a;\nmod b;\n",
                "a.rs": "use crate::b::B;\n#[cfg(test)]\nmod tests {\n    use super::*;\n}\n",
                "b.rs": "pub struct B;\n",
            }
        )
        self.assertEqual(found, [])

    def test_a_test_naming_a_sibling_back_is_a_ring(self) -> None:
        found = self.rings_of(
            {
                "lib.rs": "mod a;\nmod b;\n",
                "a.rs": "use crate::b::B;\n#[cfg(test)]\nmod tests {\n    use super::super::b;\n}\n",
                "b.rs": "pub struct B;\n#[cfg(test)]\nmod tests {\n    use crate::a;\n}\n",
            }
        )
        self.assertEqual(len(found), 1, found)

    def test_directories_naming_each_other_are_a_ring(self) -> None:
        # No two files name each other, but `x` (with its child) and `y` do.
        found = self.rings_of(
            {
                "lib.rs": "mod x;\nmod y;\n",
                "x/mod.rs": "mod inner;\nuse crate::y::Y;\n",
                "x/inner.rs": "pub struct I;\n",
                "y/mod.rs": "pub struct Y;\n#[cfg(test)]\nmod checks;\n",
                "y/checks.rs": "use crate::x::inner::I;\n",
            }
        )
        self.assertEqual(len(found), 1, found)
        self.assertIn("x -> y", found[0])
        self.assertIn("y -> x  (demo/src/y/checks.rs:1)", found[0])

    def test_a_parent_and_its_child_naming_each_other_are_a_ring(self) -> None:
        found = self.rings_of(
            {
                "lib.rs": "mod p;\n",
                "p.rs": "mod child;\nuse self::child::C;\npub struct P;\n",
                "p/child.rs": "use super::P;\npub struct C;\n",
            }
        )
        self.assertEqual(len(found), 1, found)

    def test_main_exits_one_on_a_ring_and_zero_without(self) -> None:
        with tempfile.TemporaryDirectory() as scratch:
            write_crate(Path(scratch), {"main.rs": "mod a;\nfn main() {}\n", "a.rs": ""})
            self.assertEqual(cycles.main(["module-cycles.py", scratch]), 0)
            (Path(scratch) / "demo/src/main.rs").write_text("mod a;\nmod b;\nfn main() {}\n")
            (Path(scratch) / "demo/src/a.rs").write_text("use super::b;\n")
            (Path(scratch) / "demo/src/b.rs").write_text("use super::a;\n")
            self.assertEqual(cycles.main(["module-cycles.py", scratch]), 1)


if __name__ == "__main__":
    unittest.main()
