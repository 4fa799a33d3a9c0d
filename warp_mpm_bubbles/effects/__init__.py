"""Optional effects a scene asks for by name: foam, sub-grid bubbles, entrainment, emitters and
colliders. Each module owns its settings (the scene keys and their checks), its stage and its kernels."""
