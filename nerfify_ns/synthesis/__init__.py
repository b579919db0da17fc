"""Stage 3: grammar-guided generation of Nerfstudio plugin packages."""
