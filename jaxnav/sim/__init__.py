"""jaxnav.sim"""
