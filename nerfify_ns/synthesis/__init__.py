"""Stages 1, 3 and 4 (the plan derived, fitted to the scene, rendered as a plugin): grammar-guided generation of
Nerfstudio plugin packages."""
