"""OpenCL host code. The only part of hdrcl that imports pyopencl.

* :mod:`hdrcl.cl.context` -- device choice, one context, queue and built program per
  process.
* :mod:`hdrcl.cl.processing` -- the base class of the processors.
* :mod:`hdrcl.cl.fusion` -- :class:`FusionProcessor` (``kernels/fusion.cl``).
* :mod:`hdrcl.cl.exposure` -- :class:`ExposureProcessor` (``kernels/exposure.cl``).
* :mod:`hdrcl.cl.align` -- median threshold bitmaps and shift costs (``kernels/align.cl``).
"""
