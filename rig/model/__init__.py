"""The planar grand-piano action model: kernel, integrators, simulation."""
