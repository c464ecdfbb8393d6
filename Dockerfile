# The SAGE dashboard in an image with the pinned environment: the same set-up as a fresh machine
# (scripts/setup.sh: torch 2.13.0 CPU first, then requirements.lock), into /opt/sage-venv.
# Build and run with `docker compose up --build` (see docker-compose.yml).
FROM python:3.11-slim-bookworm

# make for the Makefile targets (the healthcheck uses the venv's Python, no curl needed).
RUN apt-get update -qq \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends make \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /sage
# setup.sh installs the project editable, so it needs the whole source tree (.dockerignore keeps
# the host's .venv, caches and recorded sessions out).
COPY . .

# PyPI's default torch wheel for Linux is the CUDA build (gigabytes); the CPU wheel comes from
# PyTorch's CPU index, as SAGE_TORCH_INDEX tells setup.sh.
ENV SAGE_VENV=/opt/sage-venv \
    SAGE_TORCH_INDEX=https://download.pytorch.org/whl/cpu \
    PATH=/opt/sage-venv/bin:$PATH \
    PYTHONUNBUFFERED=1
RUN bash scripts/setup.sh && rm -rf /root/.cache/pip

EXPOSE 8000
VOLUME ["/sage/sessions"]
# Inside the container the server binds every interface so the published port reaches it;
# docker-compose.yml publishes it on the host's loopback only.
CMD ["sage", "serve", "--host", "0.0.0.0", "--port", "8000", "--sessions", "/sage/sessions"]
