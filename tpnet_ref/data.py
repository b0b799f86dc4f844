"""placeholder"""
def add_cli(sub):
    pass
