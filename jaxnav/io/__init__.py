"""jaxnav.io"""
