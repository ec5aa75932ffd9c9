"""Helpers shared by the Python rostests of this folder."""
from catkin.find_in_workspaces import find_in_workspaces


def tool(project, name):
    """The built executable `name` of `project` (devel or install space)."""
    found = find_in_workspaces(["libexec"], project=project, path=name, first_match_only=True)
    if not found:
        raise RuntimeError("%s/%s is not built" % (project, name))
    return found[0]
