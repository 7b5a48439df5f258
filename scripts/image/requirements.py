"""Print the project's requirements and those of the extras named on the command line, one a
line, read from pyproject.toml (the one place they are written).

The images write this list in a stage of its own and install it in a layer keyed on the list
alone, before the sources are copied in: a change to the code, the README or the rest of
pyproject.toml rebuilds only the small `pip install --no-deps .` layer above it, not every
dependency. Run from the folder that holds pyproject.toml:
    python requirements.py api worker > /tmp/requirements.txt
"""

import sys
import tomllib

with open("pyproject.toml", "rb") as file:
    project = tomllib.load(file)["project"]
lines = list(project["dependencies"])
for extra in sys.argv[1:]:
    lines += project["optional-dependencies"][extra]
print("\n".join(lines))
