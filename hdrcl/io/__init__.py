"""Files in and out: decoding frames (OpenImageIO, LibRaw), EXIF and exposure metadata,
writing radiance maps and images atomically. The only layer that imports OpenImageIO.
"""
