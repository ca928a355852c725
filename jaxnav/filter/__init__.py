"""jaxnav.filter"""
