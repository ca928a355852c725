"""jaxnav.gnss"""
