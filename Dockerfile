# textile_fenicsx on Debian 13 (trixie): the packages of debian-packages.txt (the list bin/fenicsx-env
# installs too) and this package. docs/environment.md "Docker" has the commands; `make docker-test` runs them:
#   docker build --network=host -t textile-fenicsx .
#   mkdir -p output
#   docker run --rm --network=none --user "$(id -u):$(id -g)" -v "$PWD/output:/work/output" textile-fenicsx
#   docker run --rm --network=none --user "$(id -u):$(id -g)" -v "$PWD/output:/work/output" \
#       textile-fenicsx mpirun -n 2 python3 demos/orthogonal_3d.py
FROM debian:trixie

# Run-time settings, the same as bin/fenicsx-env's (DESIGN.md section 10). HOME is a folder any user
# id can write to: the form compiler's cache ($HOME/.cache/fenics), matplotlib's config and
# Hypothesis's example database (the tests) live there.
# The OpenMPI run-as-root variables only matter when the container runs as root.
ENV HOME=/home/textile-fenicsx HYPOTHESIS_STORAGE_DIRECTORY=/home/textile-fenicsx/.hypothesis \
    OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 \
    OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 \
    OMPI_MCA_btl=self,sm OMPI_MCA_btl_vader_single_copy_mechanism=none \
    PRTE_MCA_rmaps_default_mapping_policy=:oversubscribe OMPI_MCA_mpi_yield_when_idle=1 \
    PYTHONDONTWRITEBYTECODE=1

# The FEniCSx stack, plus tini (for the image only, so not in the shared list), without recommended
# packages (they add about 0.6 GB and change no result), documentation, manual pages, translations
# or (on amd64) static libraries: dpkg leaves those out, about 0.3 GB. Nothing here links statically;
# the form compiler's shared modules need only libc_nonshared.a, which stays, as do the licences.
COPY debian-packages.txt /tmp/debian-packages.txt
RUN printf '%s\n' 'path-exclude=/usr/share/doc/*' 'path-include=/usr/share/doc/*/copyright' \
        'path-exclude=/usr/share/man/*' 'path-exclude=/usr/share/info/*' 'path-exclude=/usr/share/locale/*' \
        'path-exclude=/usr/lib/x86_64-linux-gnu/*.a' 'path-include=/usr/lib/x86_64-linux-gnu/*_nonshared.a' \
        >/etc/dpkg/dpkg.cfg.d/textile-fenicsx-slim \
 && export DEBIAN_FRONTEND=noninteractive \
 && apt-get update \
 && sed -e 's/#.*//' /tmp/debian-packages.txt | xargs apt-get install -y --no-install-recommends tini \
 && apt-get clean && rm -rf /var/lib/apt/lists/* /tmp/debian-packages.txt \
 && install -d -m 1777 "$HOME" /tmp/.X11-unix

# The repository (.dockerignore lets in the tracked files only) and the package, built from a copy
# so that /work gets no build/ or *.egg-info. The check imports the stack, and every module of the
# source tree from the installed package (bin/check-install).
WORKDIR /work
COPY . /work
RUN cp -r /work /tmp/src \
 && pip install --no-deps --no-build-isolation --no-cache-dir --break-system-packages \
        --root-user-action=ignore /tmp/src \
 && rm -rf /tmp/src \
 && cd / \
 && python3 -c "import dolfinx, dolfinx_mpc, textile_fenicsx; \
assert dolfinx.__version__.startswith('0.9.'), dolfinx.__version__; \
assert textile_fenicsx.__file__.startswith('/usr/local/lib/'), textile_fenicsx.__file__; \
print('build check: dolfinx', dolfinx.__version__, 'and dolfinx_mpc import;', textile_fenicsx.__file__)" \
 && python3 /work/bin/check-install /work \
 && textile-fenicsx --version

# tini runs as PID 1 and passes signals on: Ctrl-C and `docker stop` reach the job even while Python
# starts (a PID 1 that has not set a handler yet ignores them), and it reaps mpirun's children.
ENTRYPOINT ["tini", "-s", "--"]
CMD ["python3", "demos/satin_4hs.py"]
