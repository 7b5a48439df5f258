"""Print the project's requirements and those of the extras named on the command line, one a
line, read from pyproject.toml (the one place they are written).

The images install these in a layer of their own before the sources are copied in, so a change
to the code rebuilds only the small `pip install --no-deps .` layer above them, not every
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
