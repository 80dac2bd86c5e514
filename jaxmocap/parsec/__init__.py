"""PARSEC bodytrack's tracker (a wing of the core): its body model, likelihood, input folders and run."""

from jaxmocap.geometry import body as _body
from jaxmocap.parsec import model as _model

_body.register_preset("parsec31", _model.parsec31, _model.parsec31_in_metres)
