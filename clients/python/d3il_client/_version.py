"""The client's version and the API version it speaks."""

#: This package's version (PEP 440). Its major version is :data:`API_VERSION`.
__version__ = "1.0.0"

#: The API version this client speaks: the server's ``info.version`` in
#: ``/api/v1/openapi.json``.
API_VERSION = "1"
