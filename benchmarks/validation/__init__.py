"""How close the physics comes to a reference: analytic, published or the study's own finest run."""
