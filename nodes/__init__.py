"""Built-in nodes: one folder per room of the graph (DESIGN.md "Layout")."""
