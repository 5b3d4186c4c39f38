"""The SCART man-in-the-middle attack layer."""
