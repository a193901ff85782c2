# One image for every racestack service (each container runs one `python -m services.<name>`).
FROM python:3.11-slim
# gcc compiles the planner's problem functions once (cached in /cache); without it the
# planner still runs, uncompiled.
RUN apt-get update && apt-get install -y --no-install-recommends gcc libc6-dev \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /app
COPY pyproject.toml README.md ./
COPY shared ./shared
COPY services ./services
RUN pip install --no-cache-dir .
ENV RACESTACK_CACHE=/cache XDG_CONFIG_HOME=/tmp/xdg XDG_DATA_HOME=/tmp/xdg
ENTRYPOINT ["python", "-m"]
