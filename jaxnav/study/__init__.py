"""jaxnav.study"""
