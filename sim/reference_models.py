"""Rewrite the reference MJCF files of the default parameters beside the model builder.

    python -m sim.reference_models

``models/gim8108_testbed/testbed_<fixture>.xml`` are the default parameters' models, kept for reading; a test
checks they are what :func:`models.gim8108_testbed.build.build_xml` makes of :class:`sim.params.TestbedParams`.
"""

from __future__ import annotations

import argparse

from models.gim8108_testbed.build import build_xml, reference_xml_path
from models.gim8108_testbed.derived import FIXTURES
from sim.params import TestbedParams


def main(argv: list[str] | None = None) -> None:
    argparse.ArgumentParser(description=__doc__).parse_args(argv)
    for fixture in FIXTURES:
        path = reference_xml_path(fixture)
        path.write_text(build_xml(TestbedParams(), fixture))
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
