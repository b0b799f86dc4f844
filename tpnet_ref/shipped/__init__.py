"""The default m = 4 weights as package data (a link to weights/tpnet-m4.h5 in the repository;
the file itself inside a built wheel)."""
