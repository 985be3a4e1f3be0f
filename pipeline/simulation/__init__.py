"""Forward simulation: does the printed flat sheet rise into the target in the bath?"""
