"""The one build step pyproject.toml cannot say: the example scenarios travel in the wheel.

Everything else about the package is in pyproject.toml. The shipped scenarios
(`scenarios/`: the case study, its app configs under apps/, the sweeps) lie
outside the seven packages, whose top-level names the design fixes; the wheel
carries their `.toml` files as `master/examples/`, and `v2i examples DIR`
(master/scenario/examples_cli.py) copies them out for an installed user
(docs/installing.md). Only `.toml` files, never what a run left there (the
keys it provisioned under scenarios/keys/). An editable install needs no copy:
`v2i examples` reads the checkout's scenarios/ itself.
"""
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

EXAMPLES = Path("scenarios")
INSTALLED_AS = Path("master") / "examples"


def example_files() -> list[Path]:
    """The example files, relative to scenarios/."""
    return sorted(p.relative_to(EXAMPLES) for p in EXAMPLES.rglob("*.toml") if "keys" not in p.parts)


class BuildPyWithExamples(build_py):
    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return
        for relative in example_files():
            target = Path(self.build_lib) / INSTALLED_AS / relative
            self.mkpath(str(target.parent))
            self.copy_file(str(EXAMPLES / relative), str(target))


setup(cmdclass={"build_py": BuildPyWithExamples})
