"""The web viewer: a model's GLSL export in a self-contained WebGL 2 page (`viewer.write_viewer`), the page's
scene in torch (`scene`), and a headless-Chromium runner for it (`headless`)."""
