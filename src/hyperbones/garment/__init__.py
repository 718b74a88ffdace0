"""Garments: the Garment type, OBJ / MakeHuman import, procedural templates, the drape and the
draped-garment cache (``garment.draped``)."""

from hyperbones.garment.garment import Garment
from hyperbones.garment.mhclo import list_pieces, load_mhclo_garment
from hyperbones.garment.obj_io import load_obj_garment, write_obj_garment
from hyperbones.garment.templates import DEFAULT_VERTICES, TEMPLATES, make_template

__all__ = ["Garment", "DEFAULT_VERTICES", "TEMPLATES", "list_pieces", "load_mhclo_garment", "load_obj_garment",
           "make_template", "write_obj_garment"]
