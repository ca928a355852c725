"""jaxnav.ins"""
