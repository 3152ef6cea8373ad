"""The add-on's operators (thin: settings -> backend command -> results into the scene)."""

from . import backend_env, capture, decompose, edit, interop, job, layers, lights, render

CLASSES = (*job.CLASSES, *backend_env.CLASSES, *capture.CLASSES, *decompose.CLASSES, *layers.CLASSES,
           *interop.CLASSES, *edit.CLASSES, *lights.CLASSES, *render.CLASSES)
