#!/usr/bin/env bash
# The README's commands for a user, in the README's order: .ci/run runs them on the base install (`pip install .`,
# no extras) from a scratch directory that holds a link to scenes/, as a user runs them from a clone.
# tests/test_readme_commands.py checks that these lines are the commands of the README's ```sh blocks, less the
# installs (`pip install ...`, which .ci/run does itself) and the test command (`pytest`).
set -euo pipefail

warp-verlet run scenes/swinging_cloth.toml --preview
warp-verlet preview swinging_cloth.usdc -o swinging_cloth.gif --frames ::10
warp-verlet validate scenes/swinging_cloth.toml
