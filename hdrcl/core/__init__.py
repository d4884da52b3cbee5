"""The method (Debevec & Malik 1997): brackets, response solve, sampling, weights,
exposure fit, fusion and virtual exposure host logic with their float64 NumPy twins,
deghosting, alignment, radiometric scale and the merge engine.
"""
